"""conflictbench's entry point for this distribution: registers ``pi0``, ``pi0-fast`` and ``pi05``."""

from __future__ import annotations

import functools

from conflictbench import hookimpl

from .checkpoints import POLICY_TYPES
from .client import PiConfig, load


@hookimpl
def conflictbench_register_policies(register):
    for name in POLICY_TYPES:
        register(name, load=functools.partial(load, name), config=PiConfig)
