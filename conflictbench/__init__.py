"""conflictbench: how VLA policies behave when the premise of their task is false.

The public plugin API is re-exported here: the contract (``conflictbench.core``; its hooks in
``conflictbench.core.hookspecs``) and the client for models behind a server (``conflictbench.hosting``).
"""

from importlib import metadata as _metadata

from .core import (
    P1_PREAMBLE,
    ActionContext,
    ConflictCase,
    EpisodeRecord,
    InfrastructureError,
    Observation,
    Pair,
    PerEpisode,
    PrivilegedState,
    ServerUnavailable,
    UserError,
    default_format_prompt,
    hookimpl,
    rng_for,
    sampling_seed,
)
from .core.plugins import DISABLE_PLUGINS_VARIABLE  # the command line's --disable-plugins sets it
from .core.registry import published_results, read_published
from .hosting import (
    HostedConfig,
    HostedPolicy,
    HttpJsonTransport,
    PolicyClient,
    ServedPolicy,
    ServerProcess,
    ServingConfig,
    Transport,
    free_port,
    model_environment,
)

try:
    __version__ = _metadata.version("conflictbench")
except _metadata.PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

#: Modules whose hook implementations ship with conflictbench (registered like any plugin).
BUILTIN_PLUGINS = ("conflictbench.policies", "conflictbench.metrics", "conflictbench.tasks")


def plugins(**kwargs):
    """A plugin manager with the built-ins and every installed third-party plugin not disabled
    (``disabled=[...]``, by default those ``CONFLICTBENCH_DISABLE_PLUGINS`` names)."""
    import os

    from .core.plugins import Plugins

    kwargs.setdefault("disabled", os.environ.get(DISABLE_PLUGINS_VARIABLE, "").split(","))
    return Plugins(BUILTIN_PLUGINS, **kwargs)


__all__ = [
    # records a plugin sees, and the hook marker
    "ActionContext",
    "ConflictCase",
    "EpisodeRecord",
    "Observation",
    "Pair",
    "PrivilegedState",
    "hookimpl",
    # the prompt conditions: the P1 preamble and the core's default text, for a model's own template
    "P1_PREAMBLE",
    "default_format_prompt",
    # per-episode state and seeded sampling for policies
    "PerEpisode",
    "rng_for",
    "sampling_seed",
    # the shared client for served policies: what a model plugin needs to talk to its server
    "HttpJsonTransport",
    "InfrastructureError",
    "PolicyClient",
    "ServedPolicy",
    "HostedConfig",
    "HostedPolicy",
    "ServerUnavailable",
    "ServingConfig",
    "Transport",
    "UserError",
    # a model's server started for a run, in the model environment set-up made
    "ServerProcess",
    "free_port",
    "model_environment",
    # a model plugin's published LIBERO figures, read from its data file
    "published_results",
    "read_published",
    # the plugin manager
    "BUILTIN_PLUGINS",
    "plugins",
    "__version__",
]
