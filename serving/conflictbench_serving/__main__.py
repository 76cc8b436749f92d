"""``python -m conflictbench_serving POLICY --checkpoint DIR ...``: the ``conflictbench-serve`` command."""

import sys

from .command import main

sys.exit(main())
