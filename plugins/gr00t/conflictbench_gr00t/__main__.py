"""Deprecated (goes in conflictbench 0.4.0): ``python -m conflictbench_gr00t serve ...``,
like ``conflictbench-gr00t serve``, runs ``conflictbench-serve POLICY ...`` after a warning."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-gr00t"))
