"""Built-in policies, registered through the same hook as any third-party plugin.

Each policy's module is imported when the policies are registered, not by this package: an episode's code identity
holds the modules its rollout runs (``sim/rollout_code.py``), so editing the scripted expert replays the scripted
and oracle episodes, not the subject's.
"""

from __future__ import annotations

import importlib

from conflictbench.core import hookimpl

#: The names this package lends, by the module that holds them (imported on first use, PEP 562).
EXPORTS = {
    "NoopPolicy": "simple", "RandomConfig": "simple", "RandomPolicy": "simple",
    "OraclePolicy": "scripted", "ScriptedConfig": "scripted", "ScriptedPolicy": "scripted",
    "SubjectConfig": "subject.policy", "SubjectPolicy": "subject.policy",
}  # fmt: skip


@hookimpl
def conflictbench_register_policies(register):
    from .scripted import OraclePolicy, ScriptedConfig, ScriptedPolicy
    from .simple import RandomConfig, RandomPolicy, noop
    from .subject.policy import SubjectConfig, SubjectPolicy

    register("noop", load=noop)
    register("random", load=RandomPolicy, config=RandomConfig)
    register("scripted", load=ScriptedPolicy, config=ScriptedConfig)
    register("oracle", load=OraclePolicy, config=ScriptedConfig)
    register("subject", load=SubjectPolicy, config=SubjectConfig)


def __getattr__(name: str):
    if name not in EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{EXPORTS[name]}"), name)


__all__ = sorted(EXPORTS)
