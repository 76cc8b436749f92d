"""conflictbench: how VLA policies behave when the premise of their task is false.

The public plugin API is re-exported here; see ``conflictbench.core.hookspecs`` for the hooks.
"""

from importlib import metadata as _metadata

from .core import (
    ActionContext,
    ConflictCase,
    EpisodeRecord,
    Observation,
    Pair,
    PerEpisode,
    PrivilegedState,
    hookimpl,
    rng_for,
    sampling_seed,
)

try:
    __version__ = _metadata.version("conflictbench")
except _metadata.PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

#: Modules whose hook implementations ship with conflictbench (registered like any plugin).
BUILTIN_PLUGINS = ("conflictbench.policies", "conflictbench.metrics", "conflictbench.tasks")


def plugins(**kwargs):
    """A plugin manager with the built-ins and every installed third-party plugin."""
    from .core.plugins import Plugins

    return Plugins(BUILTIN_PLUGINS, **kwargs)


__all__ = [
    "ActionContext", "ConflictCase", "EpisodeRecord", "Observation", "Pair", "PerEpisode", "PrivilegedState",
    "BUILTIN_PLUGINS", "hookimpl", "plugins", "rng_for", "sampling_seed", "__version__",
]

# The shared client for served policies: what a model plugin needs to talk to its server.
from .core import (  # noqa: E402
    HttpJsonTransport,
    InfrastructureError,
    PolicyClient,
    ServedPolicy,
    ServerUnavailable,
    ServingConfig,
    Transport,
)

__all__ += ["HttpJsonTransport", "InfrastructureError", "PolicyClient", "ServedPolicy", "ServerUnavailable",
            "ServingConfig", "Transport"]
