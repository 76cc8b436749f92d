"""Built-in policies, registered through the same hook as any third-party plugin."""

from __future__ import annotations

from conflictbench.core import hookimpl

from .scripted import OraclePolicy, ScriptedConfig, ScriptedPolicy
from .simple import NoopPolicy, RandomConfig, RandomPolicy
from .subject.policy import SubjectConfig, SubjectPolicy


@hookimpl
def conflictbench_register_policies(register):
    register("noop", load=lambda cfg: NoopPolicy())
    register("random", load=RandomPolicy, config=RandomConfig)
    register("scripted", load=ScriptedPolicy, config=ScriptedConfig)
    register("oracle", load=OraclePolicy, config=ScriptedConfig)
    register("subject", load=SubjectPolicy, config=SubjectConfig)


__all__ = [
    "NoopPolicy",
    "OraclePolicy",
    "RandomConfig",
    "RandomPolicy",
    "ScriptedConfig",
    "ScriptedPolicy",
    "SubjectConfig",
    "SubjectPolicy",
]
