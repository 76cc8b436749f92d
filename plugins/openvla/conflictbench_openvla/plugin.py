"""conflictbench's entry point for this distribution: registers ``openvla`` and ``openvla-oft``."""

from __future__ import annotations

import functools

from conflictbench import hookimpl

from .client import POLICIES, load


@hookimpl
def conflictbench_register_policies(register):
    for name, (_policy, config) in POLICIES.items():
        register(name, load=functools.partial(load, name), config=config)
