"""conflictbench's entry point for this distribution: registers ``gr00t``."""

from __future__ import annotations

import functools

from conflictbench import hookimpl

from .client import Gr00tConfig, load


@hookimpl
def conflictbench_register_policies(register):
    register("gr00t", load=functools.partial(load, "gr00t"), config=Gr00tConfig)
