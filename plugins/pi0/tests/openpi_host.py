"""openpi's own server hosting our backend: the independent counterpart of ``conflictbench-serve pi0`` in tests.

Run with the model environment's python (``openpi-server==0.1.0`` and ``openpi-client==0.1.2``
installed there with ``--no-deps``: their pins ask for numpy < 2, while the server path needs only
msgpack, numpy and websockets, which lerobot already brings)::

    python tests/openpi_host.py --checkpoint DIR [--host 127.0.0.1] [--port 8000] [--threads 1]

openpi-server's ``WebsocketPolicyServer`` calls ``infer(obs)`` once per request, one at a time; the
adapter hands that observation to the backend as a batch of one. The port is bound after loading, so
``/healthz`` answering means ready.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import torch
from openpi_server import WebsocketPolicyServer

from conflictbench_pi0.backend import load_backend


class SingleRequestPolicy:
    """openpi's policy interface (``infer(obs) -> {"actions": ...}``) over a batching backend."""

    def __init__(self, backend) -> None:
        self.backend = backend

    def infer(self, obs: dict) -> dict:
        return {"actions": np.asarray(self.backend.infer_batch([obs])[0])}

    def reset(self) -> None:
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, type=Path)
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(args.threads)
    backend = load_backend(args.checkpoint, device=args.device)
    policy = SingleRequestPolicy(backend)
    server = WebsocketPolicyServer(policy, host=args.host, port=args.port, metadata=backend.metadata)
    print(f"openpi_host: loaded {args.checkpoint}; serving on ws://{args.host}:{args.port}", flush=True)
    server.serve_forever()


if __name__ == "__main__":
    main()
