"""Deprecated (goes in conflictbench 0.4.0): ``python -m conflictbench_openvla serve ...``,
like ``conflictbench-openvla serve``, runs ``conflictbench-serve POLICY ...`` after a warning."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-openvla"))
