"""The contract every plugin sees. Imports nothing else of conflictbench, no simulator, no torch."""

from .errors import ConflictbenchError, PluginError, PolicyError, SimulatorUnavailable, UserError
from .errors import InfrastructureError, ServerUnavailable
from .hookspecs import hookimpl, hookspec
from .plugins import MetricSpec, Plugins, PolicySpec
from .policy import DEFAULT_MAX_STEPS, PerEpisode, Policy, PolicyTraits, as_action_chunk
from .prompts import P1_PREAMBLE, default_format_prompt
from .records import (
    ACTION_DIM,
    FAMILIES,
    LEVELS,
    LIBERO_SUITES,
    PROMPT_CONDITIONS,
    SIMULATOR_ERROR_PREFIX,
    ActionContext,
    ConflictCase,
    EpisodeRecord,
    JointInfo,
    Observation,
    OrientedBoxes,
    Pair,
    PrivilegedState,
    SceneGeometry,
    SiteInfo,
)
from .sampling import rng_for, sampling_seed

__all__ = [
    "ACTION_DIM", "ActionContext", "ConflictCase", "ConflictbenchError", "DEFAULT_MAX_STEPS",
    "EpisodeRecord", "FAMILIES", "JointInfo", "LEVELS", "LIBERO_SUITES", "MetricSpec", "Observation",
    "OrientedBoxes", "P1_PREAMBLE", "PROMPT_CONDITIONS", "Pair", "PerEpisode", "PluginError", "Plugins", "Policy",
    "PolicyError", "PolicySpec", "PolicyTraits", "PrivilegedState", "SIMULATOR_ERROR_PREFIX", "SceneGeometry",
    "SimulatorUnavailable", "SiteInfo", "UserError", "as_action_chunk", "default_format_prompt", "hookimpl",
    "hookspec", "rng_for", "sampling_seed",
]

# The shared client for served policies (model plugins), and the errors it raises.
from .records import INFRASTRUCTURE_ERROR_PREFIX  # noqa: E402
from .serving import HttpJsonTransport, PolicyClient, ServedPolicy, ServingConfig, Transport  # noqa: E402

__all__ += ["HttpJsonTransport", "INFRASTRUCTURE_ERROR_PREFIX", "InfrastructureError", "PolicyClient",
            "ServedPolicy", "ServerUnavailable", "ServingConfig", "Transport"]
