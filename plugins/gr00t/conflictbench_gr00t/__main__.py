"""``python -m conflictbench_gr00t serve ...``: ``conflictbench-gr00t serve``, as ``conflictbench-serve POLICY``."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-gr00t"))
