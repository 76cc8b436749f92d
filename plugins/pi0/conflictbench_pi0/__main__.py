"""``python -m conflictbench_pi0 serve ...``: the same as the ``conflictbench-pi0`` console script."""

import sys

from conflictbench_pi0.cli import main

sys.exit(main())
