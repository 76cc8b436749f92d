"""NVIDIA's GR00T inference protocol, served with batching: every client's rows join the next model call.

NVIDIA's ``PolicyServer`` binds a ZeroMQ REP socket and answers one request at a time. Ours binds a ROUTER
socket, which the same REQ clients talk to unchanged, so requests of many clients (one per simulator worker)
are read as they come and their rows handed to conflictbench-serving's batcher (one model thread, a fixed call
shape of ``max_batch`` rows; the backend runs each distinct row as its own forward pass, see :mod:`.backend`).
Every row of one request gets the request's seed.

What NVIDIA's server does, kept: ``{"endpoint", "data"}`` requests (``get_action`` when no endpoint is named),
``ping``, ``reset``, ``get_modality_config``, the API token, ``[action, info]`` replies with ``action.<name>``
float32 (B, T, D), and ``{"error": message}`` for every failure (an unknown endpoint, a malformed observation, a
failed model call, a reply that cannot be built), the server going on. ``kill`` is refused (the process that
started the server stops it). Ours adds ``conflictbench_metadata`` (what is hosted) and the per-request seed in
``options``.

This module imports neither conflictbench nor torch: it runs in the model environment.
"""

from __future__ import annotations

import asyncio
import logging
import signal
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import zmq
import zmq.asyncio

from conflictbench_serving.batching import Batcher, ServerStopping

from .protocol import (
    ERROR,
    GET_ACTION,
    LANGUAGE_KEY,
    METADATA,
    PING,
    InvalidRequest,
    packb,
    request_seed,
    unpackb,
    validate_observation,
)

logger = logging.getLogger(__name__)


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


class Gr00tPolicyServer:
    """Serves ``backend`` over ZeroMQ to any number of REQ clients, one model call at a time."""

    def __init__(self, backend: Backend, max_batch: int = 8, api_token: str | None = None) -> None:
        self.batcher = Batcher(backend.infer_batch, max_batch, fixed_shape=True, name="gr00t")
        self.metadata = {**backend.metadata, "max_batch": max_batch, "fixed_shape": True}
        self.api_token = api_token

    async def answer(self, message: bytes) -> Any:
        """The reply to one message (never raises for a client's mistake or a failed model call)."""
        try:
            request = unpackb(message)
            if not isinstance(request, dict):
                raise InvalidRequest(f"a request must be a map, got {type(request).__name__}")
            if self.api_token is not None and request.get("api_token") != self.api_token:
                return {ERROR: "Unauthorized: Invalid API token"}
            endpoint, data = request.get("endpoint", GET_ACTION), request.get("data") or {}
            if endpoint == PING:
                return {"status": "ok", "message": "Server is running"}
            if endpoint == METADATA:
                return self.metadata
            if endpoint == "reset":
                return {}
            if endpoint == "get_modality_config":
                return {}
            if endpoint != GET_ACTION:
                raise InvalidRequest(f"Unknown endpoint: {endpoint}")
            if not isinstance(data, dict):
                raise InvalidRequest(f"'data' must be a map, got {type(data).__name__}")
            rows = split_rows(data.get("observation"), request_seed(data.get("options")))
            answers = await asyncio.gather(*(self.batcher.submit(row) for row in rows))
            actions = {key: np.stack([chunk[key] for chunk, _ in answers]).astype(np.float32) for key in answers[0][0]}
        except ServerStopping:
            raise
        except Exception as error:  # NVIDIA's server answers every failure as {"error": ...} and goes on
            text = str(error) if isinstance(error, InvalidRequest) else f"{type(error).__name__}: {error}"
            return {ERROR: text}
        return [actions, {"batch_size": answers[0][1]["batch_size"]}]

    async def run(self, host: str, port: int, stop: asyncio.Event, on_ready: Callable[[str, int], None] | None = None):
        """Serve on ``tcp://host:port`` (``port`` 0: any free one) until ``stop`` is set."""
        context = zmq.asyncio.Context()
        socket = context.socket(zmq.ROUTER)
        socket.setsockopt(zmq.LINGER, 0)
        batcher = asyncio.create_task(self.batcher.run(), name="batcher")
        handlers: set[asyncio.Task] = set()
        try:
            try:
                if port == 0:
                    port = socket.bind_to_random_port(f"tcp://{host}")
                else:
                    socket.bind(f"tcp://{host}:{port}")
            except zmq.ZMQError as error:  # the serve command reports an OSError as "cannot listen on ..."
                raise OSError(error.errno, error.strerror) from None
            if on_ready is not None:
                on_ready(host, port)
            receiving = asyncio.ensure_future(socket.recv_multipart())
            stopping = asyncio.ensure_future(stop.wait())
            while True:
                await asyncio.wait({receiving, stopping}, return_when=asyncio.FIRST_COMPLETED)
                if stopping.done():
                    receiving.cancel()
                    break
                frames = receiving.result()
                receiving = asyncio.ensure_future(socket.recv_multipart())
                handler = asyncio.create_task(self._reply(socket, frames))
                handlers.add(handler)
                handler.add_done_callback(handlers.discard)
        finally:
            batcher.cancel()
            await asyncio.gather(batcher, *handlers, return_exceptions=True)
            self.batcher.shutdown()
            socket.close()
            context.term()

    async def _reply(self, socket: zmq.asyncio.Socket, frames: list[bytes]) -> None:
        *envelope, message = frames  # a REQ client's identity and empty delimiter, then its message
        try:
            reply = packb(await self.answer(message))
        except ServerStopping:
            return
        except Exception as error:  # a reply that cannot be built is still an answer: the client must not wait
            logger.error("cannot answer a request: %s", error)
            reply = packb({ERROR: f"{type(error).__name__}: {error}"})
        try:
            await socket.send_multipart([*envelope, reply])
        except zmq.ZMQError as error:  # the socket is closing: the client reconnects and asks again
            logger.warning("cannot send a reply: %s", error)


def serve(
    backend: Backend,
    host: str = "127.0.0.1",
    port: int = 5555,
    max_batch: int = 8,
    on_ready: Callable[[str, int], None] | None = None,
    api_token: str | None = None,
) -> None:
    """Serve ``backend`` until SIGTERM or SIGINT, then return normally (call from the main thread)."""

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, stop.set)
        await Gr00tPolicyServer(backend, max_batch, api_token).run(host, port, stop, on_ready)

    asyncio.run(main())
