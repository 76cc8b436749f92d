"""VLA-JEPA's websocket protocol (starVLA's server) with batching, hosting a LeRobot checkpoint (model environment).

What upstream's server does, kept: the packed metadata first on every connection; ``{"type", "request_id",
"payload"}`` requests routed by ``type`` (``ping``; ``infer``, also when ``type`` is missing; anything else
an error reply); the reply ``{"status": "ok", "ok": True, "type": "inference_result", "request_id", "data":
{"normalized_actions": (B, chunk, 7)}}``, the model's output before un-normalization (the client
un-normalizes); a failure answered in-frame with ``"status": "error"`` (an invalid payload too: upstream's
model raises on it and its server catches that), the connection staying open. A frame that is not a msgpack
map ends the connection with a text frame and close code 1011, as upstream's does.

Ours adds: every row of every connection joins the next model call (conflictbench-serving's batcher, fixed
shape), a per-request seed (``conflictbench/noise_seed``), and metadata that says what is hosted: the
policy type, the checkpoint's fingerprint, ``max_batch``, the chunk length and the action statistics, so a
client needs no ``model.stats`` against this server.

``SERVED`` is what ``conflictbench-serve vla-jepa`` hosts (found through the server half's ``conflictbench_serving``
entry point) and what the client's ``served`` names. This module imports neither conflictbench nor torch (the
backend is imported by name, after the checks), so the client imports ``SERVED`` from it cheaply.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Protocol

import numpy as np

from conflictbench_serving.batching import ServerStopping
from conflictbench_serving.command import ServedModel
from conflictbench_serving.websocket import FatalRequest, WebsocketPolicyServer, batched, serve_until_stopped

from .checkpoints import check_checkpoint
from .protocol import InvalidRequest, Row, packb, reply, request_rows, unpackb

#: A LeRobot VLA-JEPA checkpoint.
SERVED = ServedModel.of(__package__, policies=("vla-jepa",), protocol="VLA-JEPA's websocket protocol",
                        check=lambda folder, policy, naming: check_checkpoint(folder))  # fmt: skip


class Backend(Protocol):
    """What the server needs of a model (``backend.JepaBackend`` is the real one)."""

    metadata: dict

    def infer_batch(self, rows: list[Row]) -> list[np.ndarray]: ...


class JepaPolicyServer(WebsocketPolicyServer):
    """Serves ``backend`` to any number of connections, one model call at a time, batching what waits."""

    def __init__(self, backend: Backend, max_batch: int = 8, fixed_shape: bool = True) -> None:
        super().__init__(self._answer, *batched(backend, max_batch, fixed_shape, name="vla-jepa"))

    async def _answer(self, frame: bytes | str, session: dict) -> bytes:
        try:
            message = unpackb(frame) if isinstance(frame, bytes) else None
        except Exception as error:
            raise FatalRequest(f"not a msgpack frame: {error}", "Internal server error") from None
        if not isinstance(message, dict):
            raise FatalRequest("a request must be a binary msgpack map", "Internal server error")
        request_id, kind = message.get("request_id", "default"), message.get("type", "infer")
        if kind == "ping":
            return packb(reply("ping", request_id))
        if kind != "infer":
            return packb(reply("unknown", request_id, error=f"Unsupported message type '{kind}'"))
        try:
            rows = request_rows(message.get("payload", message))
        except InvalidRequest as error:
            return packb(reply("inference_result", request_id, error=f"invalid request: {error}"))
        try:
            answers = await asyncio.gather(*(self.batcher.submit(row) for row in rows))
        except ServerStopping:
            raise
        except Exception as error:  # the model call failed: that request's answer, the server goes on
            return packb(reply("inference_result", request_id, error=f"{type(error).__name__}: {error}"))
        chunks = np.stack([chunk for chunk, _ in answers]).astype(np.float32)
        return packb(reply("inference_result", request_id, data={"normalized_actions": chunks}))


def serve(
    backend: Backend,
    host: str = "127.0.0.1",
    port: int = 8000,
    max_batch: int = 8,
    on_ready: Callable[[str, int], None] | None = None,
) -> None:
    """Serve ``backend`` until SIGTERM or SIGINT, then return normally (call from the main thread)."""
    serve_until_stopped(JepaPolicyServer(backend, max_batch), host, port, on_ready)
