"""``python -m conflictbench_univla serve ...``: how a run starts the server in the model environment."""

import sys

from .cli import main

sys.exit(main())
