"""``python -m conflictbench_pi0 serve ...``: ``conflictbench-pi0 serve``, as ``conflictbench-serve POLICY``."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-pi0"))
