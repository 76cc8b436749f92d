"""``python -m conflictbench_openvla serve ...``: ``conflictbench-openvla serve``, as ``conflictbench-serve POLICY``."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-openvla"))
