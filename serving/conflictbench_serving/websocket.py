"""A websocket policy server with openpi's framing; the request and reply format is the plugin's.

openpi's framing (openpi-client's ``websocket_policy_server``, also starVLA's for VLA-JEPA): the packed
metadata first on every connection, then one binary frame per request and one per reply; a fatal error is
a text frame with the error followed by close code 1011; ``GET /healthz`` answers ``OK``. The port is bound
only once the caller has loaded the model, so a ``/healthz`` answer means ready.

What a request holds and what a reply says differ per model: the plugin gives an ``answer`` coroutine
``answer(frame, session) -> bytes`` that parses the frame, awaits ``batcher.submit(...)`` and packs the
reply (``session`` is a dict kept per connection). It raises :class:`FatalRequest` for a request the
connection cannot go on after (openpi answers a malformed request so); any other exception is sent as its
traceback, as openpi does.
"""

from __future__ import annotations

import asyncio
import http
import traceback
from collections.abc import Awaitable, Callable

import websockets
import websockets.asyncio.server as ws_server
from websockets.frames import CloseCode

from . import msgpack_numpy
from .batching import Batcher, ServerStopping
from .loop import serve_until_stopped

__all__ = ["FatalRequest", "WebsocketPolicyServer", "batched", "serve_until_stopped"]

Answer = Callable[[bytes | str, dict], Awaitable[bytes]]


class FatalRequest(Exception):
    """Ends the connection: ``str(error)`` is sent as a text frame, then close code 1011 with ``reason``."""

    def __init__(self, text: str, reason: str = "Invalid request") -> None:
        super().__init__(text)
        self.reason = reason


def batched(backend, max_batch: int, fixed_shape: bool, name: str) -> tuple[bytes, Batcher]:
    """The metadata frame (the backend's ``metadata`` with ``max_batch`` and ``fixed_shape``, msgpack-numpy) and
    the batcher that runs ``backend.infer_batch``: the last two arguments of :class:`WebsocketPolicyServer`."""
    metadata = msgpack_numpy.packb({**backend.metadata, "max_batch": max_batch, "fixed_shape": fixed_shape})
    return metadata, Batcher(backend.infer_batch, max_batch, fixed_shape, name=name)


class WebsocketPolicyServer:
    """Serves ``answer`` to any number of connections, the model behind it batched by ``batcher``."""

    def __init__(self, answer: Answer, metadata_frame: bytes, batcher: Batcher) -> None:
        self.answer = answer
        self.metadata_frame = metadata_frame
        self.batcher = batcher

    @property
    def queued(self) -> int:
        """Requests waiting for the next batch."""
        return self.batcher.queued

    async def run(
        self,
        host: str,
        port: int,
        stop: asyncio.Event,
        on_ready: Callable[[str, int], None] | None = None,
    ) -> None:
        """Serve on ``host:port`` (``port`` 0: any free one) until ``stop`` is set.

        ``on_ready(host, port)`` is called once the socket is bound, with the port actually bound."""
        batcher = asyncio.create_task(self.batcher.run(), name="batcher")
        try:
            async with ws_server.serve(
                self._handle,
                host,
                port,
                compression=None,
                max_size=None,
                process_request=_health_check,
            ) as server:
                bound_host, bound_port = next(iter(server.sockets)).getsockname()[:2]
                if on_ready is not None:
                    on_ready(bound_host, bound_port)
                await stop.wait()
                server.close()
                # Handlers waiting for a reply must be released before the server can finish closing.
                batcher.cancel()
                await asyncio.gather(batcher, return_exceptions=True)
                await server.wait_closed()
        finally:
            batcher.cancel()
            self.batcher.shutdown()

    async def _handle(self, connection: ws_server.ServerConnection) -> None:
        await connection.send(self.metadata_frame)
        session: dict = {}
        while True:
            try:
                frame = await connection.recv()
            except websockets.ConnectionClosed:
                return
            try:
                reply = await self.answer(frame, session)
            except FatalRequest as error:
                await _fail(connection, str(error), error.reason)
                return
            except ServerStopping:
                return
            except Exception as error:
                await _fail(connection, "".join(traceback.format_exception(error)), "Internal server error")
                return
            try:
                await connection.send(reply)
            except websockets.ConnectionClosed:
                return


async def _fail(connection: ws_server.ServerConnection, text: str, reason: str) -> None:
    """openpi's failure: the error as a text frame, then close code 1011."""
    try:
        await connection.send(text)
        await connection.close(code=CloseCode.INTERNAL_ERROR, reason=f"{reason}. Details in the previous frame.")
    except websockets.ConnectionClosed:
        pass


def _health_check(connection: ws_server.ServerConnection, request: ws_server.Request) -> ws_server.Response | None:
    if request.path == "/healthz":
        return connection.respond(http.HTTPStatus.OK, "OK\n")
    return None
