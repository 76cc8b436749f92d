"""conflictbench's entry point for this distribution: registers ``openvla`` and ``openvla-oft``."""

from __future__ import annotations

import functools
from importlib import resources

from conflictbench import hookimpl, read_published

from .client import POLICIES, load


@hookimpl
def conflictbench_register_policies(register):
    for name, (_policy, config) in POLICIES.items():
        register(name, load=functools.partial(load, name), config=config)


@hookimpl
def conflictbench_register_published_results(register):
    """What the model's authors published on LIBERO, with its citations (published.toml)."""
    for entry in read_published(resources.files(__package__) / "published.toml"):
        register(**entry)
