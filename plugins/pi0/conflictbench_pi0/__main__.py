"""Deprecated (goes in conflictbench 0.4.0): ``python -m conflictbench_pi0 serve ...``,
like ``conflictbench-pi0 serve``, runs ``conflictbench-serve POLICY ...`` after a warning."""

import sys

from conflictbench_serving.command import plugin_main

sys.exit(plugin_main("conflictbench-pi0"))
