"""``python -m conflictbench.cli``: the same as the ``conflictbench`` command."""

import sys

from conflictbench.cli import main

sys.exit(main())
