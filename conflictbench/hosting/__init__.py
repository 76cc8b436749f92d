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
  ``json-numpy``); :mod:`.openvla_family`, the OpenVLA family's image and action steps (Pillow, simplejpeg). Each
  needs conflictbench's extra of its name (``conflictbench[openpi]``, ``[zeromq]``, ``[rest]``,
  ``[openvla-family]``), which the plugin requires; without it, importing the module says so in one line;
- :mod:`.former`: the names kept at their places of 0.2 (``conflictbench.core.HostedPolicy``,
  ``conflictbench.core.serving``), each use warning; they go in 0.4.0.

Imports nothing of conflictbench but :mod:`conflictbench.core`; no simulator, no torch.
"""

from . import former
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

# The names that lived in ``conflictbench.core`` until 0.2 stay usable there until 0.4, each use warning (.former).
former.install()
