"""``python -m conflictbench_vla_jepa serve ...``: the same as the ``conflictbench-vla-jepa`` console script."""

import sys

from conflictbench_vla_jepa.cli import main

sys.exit(main())
