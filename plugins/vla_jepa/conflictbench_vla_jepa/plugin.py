"""conflictbench's entry point for this distribution: registers ``vla-jepa``."""

from __future__ import annotations

import functools

from conflictbench import hookimpl

from .client import VlaJepaConfig, load


@hookimpl
def conflictbench_register_policies(register):
    register("vla-jepa", load=functools.partial(load, "vla-jepa"), config=VlaJepaConfig)
