"""The contract every plugin sees: hook specs, the policy contract and its records, registration, prompts,
errors, seeded sampling. Imports nothing else of conflictbench, no simulator, no torch.

The client for models behind a server (transports, ``PolicyClient``, ``HostedPolicy``, ``ServerProcess``) is a
layer above this one, :mod:`conflictbench.hosting`. Its names and modules, which lived here until 0.2, stay
usable from here until 0.4.0, each use warning (``DeprecationWarning``) with the new place: importing
:mod:`conflictbench.hosting` (which ``import conflictbench`` does) gives this package a ``__getattr__`` (PEP 562)
that finds them there (``hosting/former.py``), so nothing here imports upwards."""

from .errors import (
    ClientError,
    ConflictbenchError,
    InfrastructureError,
    PluginError,
    PolicyError,
    PolicyStalled,
    ServerUnavailable,
    SimulatorUnavailable,
    StoreFull,
    UserError,
)
from .hookspecs import hookimpl, hookspec
from .plugins import MetricSpec, Plugins, PolicySpec
from .policy import DEFAULT_MAX_STEPS, PerEpisode, Policy, PolicyTraits, as_action_chunk
from .prompts import P1_PREAMBLE, default_format_prompt
from .records import (
    ACTION_DIM,
    ERROR_KINDS,
    FAMILIES,
    INFRASTRUCTURE_ERROR_PREFIX,
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
    SceneState,
    SiteInfo,
)
from .sampling import rng_for, sampling_seed

__all__ = [
    "ACTION_DIM",
    "ActionContext",
    "ClientError",
    "ConflictCase",
    "ConflictbenchError",
    "DEFAULT_MAX_STEPS",
    "ERROR_KINDS",
    "EpisodeRecord",
    "FAMILIES",
    "INFRASTRUCTURE_ERROR_PREFIX",
    "InfrastructureError",
    "JointInfo",
    "LEVELS",
    "LIBERO_SUITES",
    "MetricSpec",
    "Observation",
    "OrientedBoxes",
    "P1_PREAMBLE",
    "PROMPT_CONDITIONS",
    "Pair",
    "PerEpisode",
    "PluginError",
    "Plugins",
    "Policy",
    "PolicyError",
    "PolicyStalled",
    "PolicySpec",
    "PolicyTraits",
    "PrivilegedState",
    "SceneState",
    "SIMULATOR_ERROR_PREFIX",
    "SceneGeometry",
    "ServerUnavailable",
    "SimulatorUnavailable",
    "StoreFull",
    "SiteInfo",
    "UserError",
    "as_action_chunk",
    "default_format_prompt",
    "hookimpl",
    "hookspec",
    "rng_for",
    "sampling_seed",
]
