"""NVIDIA's GR00T inference protocol, served with batching: every client's rows join the next model call.

The server is conflictbench-serving's :class:`~conflictbench_serving.zeromq.ZmqPolicyServer` (a ROUTER socket
NVIDIA's REQ clients talk to unchanged; ``ping``, ``reset``, ``get_modality_config``, the API token,
``conflictbench_metadata``, ``{"error": message}`` for every failure, the server going on). This module answers
``get_action``: the observation's rows handed to the batcher (one model thread, a fixed call shape of
``max_batch`` rows; the backend runs each distinct row as its own forward pass, see :mod:`.backend`), every row
of one request with the request's seed, and ``[action, info]`` replies with ``action.<name>`` float32 (B, T, D).

``SERVED`` is what ``conflictbench-serve gr00t`` hosts (found through the server half's ``conflictbench_serving``
entry point) and what the client's ``served`` names. This module imports neither conflictbench nor torch (the
backend is imported by name, after the checks), so the client imports ``SERVED`` from it cheaply.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from conflictbench_serving.batching import Batcher
from conflictbench_serving.command import ServedModel
from conflictbench_serving.loop import serve_until_stopped
from conflictbench_serving.zeromq import ZmqPolicyServer

from .checkpoints import check_checkpoint
from .protocol import LANGUAGE_KEY, request_seed, validate_observation

#: A LeRobot GR00T N1.7 checkpoint on NVIDIA's port.
SERVED = ServedModel.of(
    __package__,
    policies=("gr00t",),
    protocol="NVIDIA's ZeroMQ protocol",
    check=lambda folder, policy, naming: check_checkpoint(folder),
    port=5555,
    url_scheme="tcp",
)


@dataclass(frozen=True)
class Row:
    """One row of a ``get_action`` observation: its arrays (leading batch dimension 1), text and seed."""

    observation: dict[str, Any]
    instruction: str
    seed: int | None


class Backend(Protocol):
    """What the server needs of a model (``backend.GrootBackend`` is the real one)."""

    metadata: dict

    def infer_batch(self, rows: list[Row]) -> list[dict[str, np.ndarray]]:
        """Each row's actions: ``action.<name>`` float32 (T, D)."""
        ...


def split_rows(observation: dict, seed: int | None) -> list[Row]:
    """The rows of a checked observation, each with the request's seed."""
    batch = validate_observation(observation)
    arrays = {key: value for key, value in observation.items() if isinstance(value, np.ndarray)}
    return [
        Row({key: value[i : i + 1] for key, value in arrays.items()}, observation[LANGUAGE_KEY][i], seed)
        for i in range(batch)
    ]


class Gr00tPolicyServer(ZmqPolicyServer):
    """Serves ``backend`` over ZeroMQ to any number of REQ clients, one model call at a time."""

    def __init__(self, backend: Backend, max_batch: int = 8, api_token: str | None = None) -> None:
        batcher = Batcher(backend.infer_batch, max_batch, fixed_shape=True, name="gr00t")
        super().__init__(batcher, backend.metadata, api_token)

    async def get_action(self, data: dict) -> Any:
        rows = split_rows(data.get("observation"), request_seed(data.get("options")))
        answers = await asyncio.gather(*(self.batcher.submit(row) for row in rows))
        actions = {key: np.stack([chunk[key] for chunk, _ in answers]).astype(np.float32) for key in answers[0][0]}
        return [actions, {"batch_size": answers[0][1]["batch_size"]}]


def serve(
    backend: Backend,
    host: str = "127.0.0.1",
    port: int = 5555,
    max_batch: int = 8,
    on_ready: Callable[[str, int], None] | None = None,
    api_token: str | None = None,
) -> None:
    """Serve ``backend`` until SIGTERM or SIGINT, then return normally (call from the main thread)."""
    serve_until_stopped(Gr00tPolicyServer(backend, max_batch, api_token), host, port, on_ready)
