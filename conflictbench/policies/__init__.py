"""Built-in policies, registered through the same hook as any third-party plugin."""

from __future__ import annotations

from conflictbench.core import hookimpl

from .simple import NoopPolicy, RandomConfig, RandomPolicy


@hookimpl
def conflictbench_register_policies(register):
    register("noop", load=lambda cfg: NoopPolicy())
    register("random", load=RandomPolicy, config=RandomConfig)


__all__ = ["NoopPolicy", "RandomConfig", "RandomPolicy"]
