"""conflictbench's entry point for this distribution: registers ``vla-jepa``."""

from __future__ import annotations

import functools
from importlib import resources

from conflictbench import hookimpl, read_published

from .client import VlaJepaConfig, load


@hookimpl
def conflictbench_register_policies(register):
    register("vla-jepa", load=functools.partial(load, "vla-jepa"), config=VlaJepaConfig)


@hookimpl
def conflictbench_register_published_results(register):
    """What the model's authors published on LIBERO, with its citations (published.toml)."""
    for entry in read_published(resources.files(__package__) / "published.toml"):
        register(**entry)
