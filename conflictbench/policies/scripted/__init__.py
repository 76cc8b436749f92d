"""The built-in scripted expert (a privileged waypoint controller for the 40 LIBERO base tasks)
and the oracle built on it."""

from .oracle import OraclePolicy
from .policy import ScriptedConfig, ScriptedPolicy

__all__ = ["OraclePolicy", "ScriptedConfig", "ScriptedPolicy"]
