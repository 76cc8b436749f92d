"""``python -m conflictbench_univla serve ...``: ``conflictbench-univla serve``, as ``conflictbench-serve POLICY``."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-univla"))
