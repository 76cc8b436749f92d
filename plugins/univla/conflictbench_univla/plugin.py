"""conflictbench's entry point for this distribution: registers ``univla``."""

from __future__ import annotations

import functools
from importlib import resources

from conflictbench import hookimpl, read_published

from .client import UnivlaConfig, load


@hookimpl
def conflictbench_register_policies(register):
    register("univla", load=functools.partial(load, "univla"), config=UnivlaConfig)


@hookimpl
def conflictbench_register_published_results(register):
    """What the model's authors published on LIBERO, with its citations (published.toml)."""
    for entry in read_published(resources.files(__package__) / "published.toml"):
        register(**entry)
