"""``python -m conflictbench_vla_jepa serve ...``: ``conflictbench-vla-jepa serve`` (``conflictbench-serve POLICY``)."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-vla-jepa"))
