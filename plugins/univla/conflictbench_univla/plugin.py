"""conflictbench's entry point for this distribution: registers ``univla``."""

from __future__ import annotations

import functools

from conflictbench import hookimpl

from .client import UnivlaConfig, load


@hookimpl
def conflictbench_register_policies(register):
    register("univla", load=functools.partial(load, "univla"), config=UnivlaConfig)
