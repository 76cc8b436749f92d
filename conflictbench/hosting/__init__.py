"""The client layer: how conflictbench reaches a model that runs behind a server, the same for every model plugin.

A model plugin has two halves. This package is the first, loaded beside the simulator: the wire protocols'
client transports, the served-policy client with its retries and failure classes, and the lifecycle of a model
server started for a run (``model.checkpoint=DIR``). The second is ``conflictbench-serving`` (``serving/``): the
server skeletons, codecs and the ``conflictbench-serve`` command, in the model's own environment, with neither
conflictbench nor torch. A plugin keeps only what is its own: processing, backend, checkpoint checks, goldens.

- :mod:`.transport`: :class:`Transport` (one connection in one protocol) and :class:`HttpJsonTransport`;
- :mod:`.client`: :class:`ServingConfig`, :class:`PolicyClient` (a connection per stream, retries, reconnects,
  failure classes) and :class:`ServedPolicy` (``encode``/``decode`` around it);
- :mod:`.hosted`: :class:`HostedConfig` and :class:`HostedPolicy` (start, check and stop the model's own server);
- :mod:`.launch`: :class:`ServerProcess`, the server process started for one run;
- one module per native protocol, each importing its wire library, which the plugin that speaks it depends on:
  :mod:`.openpi` (openpi's websocket with msgpack-numpy: π0, π0-FAST, π0.5, and VLA-JEPA's starVLA envelope;
  ``websockets``, ``conflictbench-serving``), :mod:`.zeromq` (NVIDIA's ZeroMQ: GR00T; ``pyzmq``,
  ``conflictbench-serving``), :mod:`.rest` (``deploy.py``'s REST with json-numpy: OpenVLA, OFT, UniVLA;
  ``json-numpy``).

Imports nothing of conflictbench but :mod:`conflictbench.core`; no simulator, no torch.
"""

from .client import MAX_CONCURRENT_REQUESTS, PolicyClient, ServedPolicy, ServingConfig
from .hosted import MODEL_PROCESS_ENV, HostedConfig, HostedPolicy
from .launch import ServerProcess, free_port, model_environment
from .transport import HttpJsonTransport, Transport, one_line

__all__ = [
    "HostedConfig",
    "HostedPolicy",
    "HttpJsonTransport",
    "MAX_CONCURRENT_REQUESTS",
    "MODEL_PROCESS_ENV",
    "PolicyClient",
    "ServedPolicy",
    "ServerProcess",
    "ServingConfig",
    "Transport",
    "free_port",
    "model_environment",
    "one_line",
]

#: Modules that lived in ``conflictbench.core`` until 0.2 and the names they held: both stay importable there
#: (``from conflictbench.core import HostedPolicy``, ``from conflictbench.core.transport import one_line``), so a
#: plugin written against 0.2 runs unchanged. New code imports them from ``conflictbench`` or here.
FORMER_CORE_MODULES = {"serving": "client", "transport": "transport", "hosting": "hosted", "launch": "launch"}
FORMER_CORE_NAMES = [name for name in __all__ if name not in ("MAX_CONCURRENT_REQUESTS", "one_line")]


def _keep_former_places() -> None:
    import sys

    from .. import core

    for old, new in FORMER_CORE_MODULES.items():
        module = sys.modules[f"{__name__}.{new}"]
        sys.modules.setdefault(f"{core.__name__}.{old}", module)
        setattr(core, old, module)
    for name in FORMER_CORE_NAMES:
        setattr(core, name, globals()[name])


_keep_former_places()
