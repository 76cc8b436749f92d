"""The LeRobot server: openpi's websocket framing, one LIBERO step per request, any LeRobot checkpoint (model env).

conflictbench-serving's websocket server (openpi's framing, the hardened guard: token, frame size, connections)
answers each request with :class:`~conflictbench_lerobot.backend.LeRobotBackend`'s action for that step. Requests of
every connection queue for one model thread (conflictbench-serving's batcher), one request per call: each runs as
LeRobot's batch of one, so an episode's actions never depend on which requests were waiting beside it, and a step
that fails fails no other episode's. A request that is not a valid step, or a step out of its episode's
order, ends its connection with openpi's text frame and close code 1011, as a failing model call does.

``SERVED`` is what ``conflictbench-serve lerobot`` hosts (the server half's ``conflictbench_serving`` entry point)
and what the client's ``served`` names. This module imports neither conflictbench nor torch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from conflictbench_serving.command import ServedModel
from conflictbench_serving.websocket import FatalRequest, WebsocketPolicyServer, batched, serve_until_stopped

from .checkpoints import check_folder
from .protocol import ACTIONS, InvalidRequest, packb, unpackb, validate_request

#: Any LeRobot checkpoint, on openpi's port.
SERVED = ServedModel.of(
    __package__,
    policies=("lerobot",),
    protocol="lerobot-eval's LIBERO steps on openpi's websocket wire",
    check=lambda folder, policy, naming: check_folder(folder),
)


class Backend(Protocol):
    """What the server needs of a model (``backend.LeRobotBackend`` is the real one)."""

    metadata: dict

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]: ...


class LeRobotPolicyServer(WebsocketPolicyServer):
    """Serves ``backend`` to any number of connections, one step at a time."""

    def __init__(self, backend: Backend) -> None:
        # One request per model call: each is LeRobot's batch of one, and a step that fails fails no other episode's.
        super().__init__(self._answer, *batched(backend, 1, fixed_shape=False, name="lerobot"))

    async def _answer(self, frame: bytes | str, session: dict) -> bytes:
        try:
            if isinstance(frame, str):
                raise InvalidRequest("a request must be a binary frame, got a text frame")
            try:
                message = unpackb(frame)
            except Exception as error:
                raise InvalidRequest(f"not an openpi msgpack frame: {error}") from None
            validate_request(message)
        except InvalidRequest as error:
            raise FatalRequest(f"invalid request: {error}") from None
        action, _timing = await self.batcher.submit(message)
        return packb({ACTIONS: action})


def serve(
    backend: Backend,
    host: str = "127.0.0.1",
    port: int = 8000,
    max_batch: int = 8,
    on_ready: Callable[[str, int], None] | None = None,
) -> None:
    """Serve ``backend`` until SIGTERM or SIGINT, then return normally (call from the main thread). ``max_batch`` is
    not used: every call is one step of one episode."""
    serve_until_stopped(LeRobotPolicyServer(backend), host, port, on_ready)
