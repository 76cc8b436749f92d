"""openpi's websocket protocol, served with batching: every connection's request joins the next model call.

openpi's own ``openpi-server`` runs one ``infer()`` per request. Here conflictbench-serving's
:class:`~conflictbench_serving.batching.Batcher` hands everything queued (up to ``max_batch``) to
``backend.infer_batch`` in one worker thread; with ``fixed_shape`` (what ``serve`` and the command use) each
call is padded to exactly ``max_batch`` rows, so an episode's actions never depend on its batch company.
The metadata frame says ``max_batch`` and ``fixed_shape``.

The wire format is openpi's (see :mod:`conflictbench_pi0.protocol`): one binary frame per request and per
reply (``{"actions": chunk, "server_timing": {"infer_ms", "batch_size", "prev_total_ms"}}``;
``batch_size`` is ours), and on failure a text frame with the error followed by close code 1011. A
malformed request fails only its own connection; a failing model call fails every request of that batch.

``SERVED`` is what ``conflictbench-serve pi0`` hosts (found through the server half's ``conflictbench_serving``
entry point) and what the client's ``served`` names. This module imports neither conflictbench nor torch (the
backend is imported by name, after the checks), so the client imports ``SERVED`` from it cheaply.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from conflictbench_pi0 import protocol
from conflictbench_pi0.protocol import InvalidRequest, validate_request
from conflictbench_serving.command import ServedModel
from conflictbench_serving.websocket import FatalRequest, WebsocketPolicyServer, batched, serve_until_stopped

from .checkpoints import POLICY_TYPES, check_checkpoint

#: The π checkpoints (pi0, pi05, pi0-fast), on openpi's port.
SERVED = ServedModel.of(
    __package__,
    policies=tuple(POLICY_TYPES),
    protocol="openpi's websocket protocol",
    check=lambda folder, policy, naming: check_checkpoint(folder, policy, option=naming),
)


class Backend(Protocol):
    """What the server needs of a model (``backend.PiBackend`` is the real one)."""

    metadata: dict

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]: ...


class BatchingPolicyServer(WebsocketPolicyServer):
    """Serves ``backend`` to any number of connections, one model call at a time, batching what waits."""

    def __init__(self, backend: Backend, max_batch: int = 32, fixed_shape: bool = False) -> None:
        super().__init__(self._answer, *batched(backend, max_batch, fixed_shape, name="pi"))
        self.backend = backend

    async def _answer(self, frame: bytes | str, session: dict) -> bytes:
        started = time.monotonic()
        try:
            if isinstance(frame, str):
                raise InvalidRequest("a request must be a binary frame, got a text frame")
            try:
                request = protocol.unpackb(frame)
            except Exception as error:
                raise InvalidRequest(f"not an openpi msgpack frame: {error}") from error
            validate_request(request)
        except InvalidRequest as error:
            raise FatalRequest(f"invalid request: {error}") from None
        actions, timing = await self.batcher.submit(request)
        if "prev_total_ms" in session:
            timing = {**timing, "prev_total_ms": session["prev_total_ms"]}
        reply = protocol.packb({protocol.ACTIONS: actions, "server_timing": timing})
        session["prev_total_ms"] = (time.monotonic() - started) * 1000
        return reply


def serve(
    backend: Backend,
    host: str = "127.0.0.1",
    port: int = 8000,
    max_batch: int = 32,
    on_ready: Callable[[str, int], None] | None = None,
    fixed_shape: bool = True,
) -> None:
    """Serve ``backend`` until SIGTERM or SIGINT, then return normally (call from the main thread).

    ``fixed_shape`` (the default here): every forward pass has ``max_batch`` rows, so an episode's actions
    do not depend on which requests happened to share its calls (float rounding follows the shape)."""
    serve_until_stopped(BatchingPolicyServer(backend, max_batch, fixed_shape), host, port, on_ready)
