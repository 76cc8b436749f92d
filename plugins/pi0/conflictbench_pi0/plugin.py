"""conflictbench's entry point for this distribution: registers ``pi0``, ``pi0-fast`` and ``pi05``."""

from __future__ import annotations

import functools
from importlib import resources

from conflictbench import hookimpl, read_published

from .checkpoints import POLICY_TYPES
from .client import PiConfig, load


@hookimpl
def conflictbench_register_policies(register):
    for name in POLICY_TYPES:
        register(name, load=functools.partial(load, name), config=PiConfig)


@hookimpl
def conflictbench_register_published_results(register):
    """What the model's authors published on LIBERO, with its citations (published.toml)."""
    for entry in read_published(resources.files(__package__) / "published.toml"):
        register(**entry)
