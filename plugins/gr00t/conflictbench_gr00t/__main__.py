"""``python -m conflictbench_gr00t serve ...``: the same as the ``conflictbench-gr00t`` console script."""

import sys

from conflictbench_gr00t.cli import main

sys.exit(main())
