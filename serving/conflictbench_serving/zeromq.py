"""NVIDIA Isaac-GR00T's ZeroMQ protocol, server side: its messages, and a batching server on a ROUTER socket.

The facts, from Isaac-GR00T's ``gr00t/policy/server_client.py`` (``PolicyServer``, ``PolicyClient``,
``MsgSerializer``):

- one request, one reply, each a msgpack map; an array is the map ``{"__ndarray_class__": True, "as_npy": <the
  bytes np.save writes, allow_pickle=False>}`` (dtype and shape travel inside the .npy header); arrays of object
  dtype cannot be sent (:func:`packb`, :func:`unpackb`; one received is refused, as are structured and void ones
  and a header whose shape does not match the bytes, before the data is read: :mod:`.arrays`);
- a request is ``{"endpoint": NAME, "data": {...}}`` (``data`` left out for endpoints without input), plus
  ``"api_token"`` when the server wants one; endpoints ``ping``, ``get_action``, ``reset``,
  ``get_modality_config``, ``kill``;
- any failure answers ``{"error": message}`` (an unknown endpoint: ``"Unknown endpoint: NAME"``).

NVIDIA's ``PolicyServer`` binds a REP socket and answers one request at a time. :class:`ZmqPolicyServer` binds a
ROUTER socket, which the same REQ clients talk to unchanged, so requests of many clients (one per simulator
worker) are read as they come; a subclass answers ``get_action`` (what an observation holds is the model's) and
hands its rows to a :class:`~.batching.Batcher`. It answers ``ping``, ``reset`` and ``get_modality_config`` as
NVIDIA's does, checks the API token, refuses ``kill`` (the process that started the server stops it) and adds
``conflictbench_metadata`` (what is hosted), which NVIDIA's server answers with its unknown-endpoint error.
The client half is ``conflictbench.hosting.zeromq``.

What a peer may do is the :class:`~.guard.Guard`'s (the server's own, else the process-wide one): with a token
(the guard's, or ``api_token``), every request must carry it in ``api_token``, ``ping`` included (compared in
constant time) and is checked before any array in it is decoded; a frame over ``max_message_bytes`` is dropped by
ZeroMQ itself (``MAXMSGSIZE``: the peer is disconnected before the frame is read whole). ``MAXMSGSIZE`` bounds
each frame, not a message: messages are read frame by frame, and one with more frames than a REQ client's
(identity, empty delimiter, request) or more bytes in all than the bound is dropped, kept no further than the
frame being read and never answered (its frames would be the reply's envelope). At most ``max_queued`` requests
are handled at once (more are answered ``{"error": "ServerBusy: ..."}`` at once), and errors are one line.

Needs ``pyzmq`` (the ``zeromq`` extra). Imports neither conflictbench nor torch.
"""

from __future__ import annotations

import asyncio
import io
import logging
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import zmq
import zmq.asyncio

from .arrays import load_npy
from .batching import Batcher, ServerStopping
from .guard import Guard, current, error_line

logger = logging.getLogger(__name__)

GET_ACTION, PING, METADATA = "get_action", "ping", "conflictbench_metadata"
ERROR = "error"

_ARRAY_TAG = "__ndarray_class__"
#: A REQ client's message as a ROUTER reads it: the client's identity, the empty delimiter, the request.
REQUEST_FRAMES = 3


class InvalidRequest(ValueError):
    """A request the protocol or the model cannot take; the message is sent back as the error."""


def _encode(value: Any) -> Any:
    if isinstance(value, np.generic):  # a numpy scalar travels as the plain number it is
        return value.item()
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "O":
            raise TypeError("arrays of object dtype cannot be sent")
        buffer = io.BytesIO()
        np.save(buffer, value, allow_pickle=False)
        return {_ARRAY_TAG: True, "as_npy": buffer.getvalue()}
    return value


def _decode(obj: dict) -> Any:
    if _ARRAY_TAG in obj:
        return load_npy(obj.get("as_npy"))
    return obj


def packb(obj: Any) -> bytes:
    """``obj`` (maps, lists, strings, numbers, numpy arrays) as one message."""
    return msgpack.packb(obj, default=_encode)


def unpackb(data: bytes) -> Any:
    """The value in one message (arrays come back as writable arrays)."""
    return msgpack.unpackb(data, object_hook=_decode)


def endpoint_request(endpoint: str, api_token: str | None = None) -> dict:
    """A request for an endpoint without input (``ping``, ``conflictbench_metadata``)."""
    return {"endpoint": endpoint, **({"api_token": api_token} if api_token else {})}


class ZmqPolicyServer:
    """Serves one model to any number of REQ clients over a ROUTER socket; subclasses answer ``get_action``."""

    def __init__(
        self, batcher: Batcher, metadata: dict, api_token: str | None = None, guard: Guard | None = None
    ) -> None:
        self.batcher = batcher
        self.metadata = {**metadata, "max_batch": batcher.max_batch, "fixed_shape": batcher.fixed_shape}
        self.guard = guard  # None: the process-wide guard when the server starts
        self.api_token = api_token  # NVIDIA's option; else the guard's token
        self._serving = self._resolve()

    def _resolve(self) -> Guard:
        guard = current() if self.guard is None else self.guard
        if self.api_token is not None and self.api_token != guard.token:
            guard = Guard(self.api_token, guard.max_message_bytes, guard.max_connections, guard.max_queued)
        return guard

    async def get_action(self, data: dict) -> Any:
        """The reply to a ``get_action`` request's ``data`` (raise :class:`InvalidRequest` for a malformed one)."""
        raise NotImplementedError

    async def answer(self, message: bytes) -> Any:
        """The reply to one message (never raises for a client's mistake or a failed model call)."""
        try:
            # The token first, from the message read without its arrays: a stranger's arrays are never decoded.
            if self._serving.token is not None:
                outer = msgpack.unpackb(message)
                presented = outer.get("api_token") if isinstance(outer, dict) else None
                if not self._serving.admits(presented if isinstance(presented, str) else None):
                    return {ERROR: "Unauthorized: Invalid API token"}
            request = unpackb(message)
            if not isinstance(request, dict):
                raise InvalidRequest(f"a request must be a map, got {type(request).__name__}")
            endpoint, data = request.get("endpoint", GET_ACTION), request.get("data") or {}
            if endpoint == PING:
                return {"status": "ok", "message": "Server is running"}
            if endpoint == METADATA:
                return self.metadata
            if endpoint in ("reset", "get_modality_config"):
                return {}
            if endpoint != GET_ACTION:
                raise InvalidRequest(f"Unknown endpoint: {endpoint}")
            if not isinstance(data, dict):
                raise InvalidRequest(f"'data' must be a map, got {type(data).__name__}")
            return await self.get_action(data)
        except ServerStopping:
            raise
        except Exception as error:  # NVIDIA's server answers every failure as {"error": ...} and goes on
            return {ERROR: error_line(error, bare=(InvalidRequest,))}

    async def run(self, host: str, port: int, stop: asyncio.Event, on_ready: Callable[[str, int], None] | None = None):
        """Serve on ``tcp://host:port`` (``port`` 0: any free one) until ``stop`` is set."""
        guard = self._serving = self._resolve()
        if self.batcher.max_queued is None:
            self.batcher.max_queued = guard.max_queued
        context = zmq.asyncio.Context()
        socket = context.socket(zmq.ROUTER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, guard.max_message_bytes)  # larger: the peer is dropped, nothing is read
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
            receiving = asyncio.ensure_future(_receive(socket, guard.max_message_bytes))
            stopping = asyncio.ensure_future(stop.wait())
            while True:
                await asyncio.wait({receiving, stopping}, return_when=asyncio.FIRST_COMPLETED)
                if stopping.done():
                    receiving.cancel()
                    break
                frames = receiving.result()
                receiving = asyncio.ensure_future(_receive(socket, guard.max_message_bytes))
                if frames is None:  # not a REQ client's request: dropped, never answered
                    continue
                if len(handlers) >= guard.max_queued:  # a flood: answered at once, never held
                    busy = f"ServerBusy: {guard.max_queued} requests are being answered (max_queued)"
                    await socket.send_multipart([*frames[:-1], packb({ERROR: busy})])
                    continue
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
            logger.error("cannot answer a request", exc_info=error)
            reply = packb({ERROR: error_line(error, bare=(InvalidRequest,))})
        try:
            await socket.send_multipart([*envelope, reply])
        except zmq.ZMQError as error:  # the socket is closing: the client reconnects and asks again
            logger.warning("cannot send a reply: %s", error)


async def _receive(socket: zmq.asyncio.Socket, limit: int) -> list[bytes] | None:
    """The next message's frames, read one at a time; None (the rest read and let go, frame by frame) for one that
    is not a REQ client's request: more than :data:`REQUEST_FRAMES` frames, no empty delimiter before the last, or
    more than ``limit`` bytes in all (``MAXMSGSIZE`` has bounded each frame)."""
    frames: list[bytes] | None = [await socket.recv()]
    total = len(frames[0])
    while socket.getsockopt(zmq.RCVMORE):
        frame = await socket.recv()
        total += len(frame)
        if frames is not None and (len(frames) >= REQUEST_FRAMES or total > limit):
            frames = None
        if frames is not None:
            frames.append(frame)
    if frames is None or len(frames) != REQUEST_FRAMES or frames[1] != b"":
        logger.debug("dropped a message that is not a request (%d bytes)", total)  # a stranger must not fill the log
        return None
    return frames
