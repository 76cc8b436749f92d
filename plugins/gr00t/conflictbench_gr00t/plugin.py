"""conflictbench's entry point for this distribution: registers ``gr00t``."""

from __future__ import annotations

import functools
from importlib import resources

from conflictbench import hookimpl, read_published

from .client import Gr00tConfig, load


@hookimpl
def conflictbench_register_policies(register):
    register("gr00t", load=functools.partial(load, "gr00t"), config=Gr00tConfig)


@hookimpl
def conflictbench_register_published_results(register):
    """What the model's authors published on LIBERO, with its citations (published.toml)."""
    for entry in read_published(resources.files(__package__) / "published.toml"):
        register(**entry)
