"""A websocket policy server with openpi's framing; the request and reply format is the plugin's.

openpi's framing (openpi-client's ``websocket_policy_server``, also starVLA's for VLA-JEPA): the packed
metadata first on every connection, then one binary frame per request and one per reply; a fatal error is
a text frame with the error followed by close code 1011; ``GET /healthz`` answers ``OK``. The port is bound
only once the caller has loaded the model, so a ``/healthz`` answer means ready.

What a request holds and what a reply says differ per model: the plugin gives an ``answer`` coroutine
``answer(frame, session) -> bytes`` that parses the frame, awaits ``batcher.submit(...)`` and packs the
reply (``session`` is a dict kept per connection). It raises :class:`FatalRequest` for a request the
connection cannot go on after (openpi answers a malformed request so). Any other exception is sent as one line,
``TypeName: message`` (openpi sends its traceback; ours stays in the server's log: a peer learns nothing of our
internals), and so is a full queue (``ServerBusy: ...``).

What a peer may do is the :class:`~.guard.Guard`'s (the server's own, else the process-wide one): with a token,
the upgrade must carry ``Authorization: Api-Key <token>`` (HTTP 401 otherwise; ``/healthz`` answers without it:
it says nothing); frames over ``max_message_bytes`` close the connection with code 1009 (websockets' own check,
before the frame is read whole), and at most :data:`MAX_QUEUED_FRAMES` are read ahead of the one being answered;
beyond ``max_connections`` open connections a new one is refused with HTTP 503 (or, when many arrive at once,
closed with code 1013, try again later); the batcher queues at most ``max_queued``.
"""

from __future__ import annotations

import asyncio
import functools
import http
import logging
from collections.abc import Awaitable, Callable

import websockets
import websockets.asyncio.server as ws_server
from websockets.frames import CloseCode

from . import msgpack_numpy
from .batching import Batcher, ServerBusy, ServerStopping, logged
from .guard import AUTHORIZATION, UNAUTHORIZED, Guard, current, error_line
from .loop import serve_until_stopped

logger = logging.getLogger(__name__)

#: Frames read ahead on one connection (websockets' default is 16, each up to max_message_bytes): our clients send
#: one request and wait for its reply, so a peer that sends more is held back by TCP, not buffered here.
MAX_QUEUED_FRAMES = 2

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

    def __init__(self, answer: Answer, metadata_frame: bytes, batcher: Batcher, guard: Guard | None = None) -> None:
        self.answer = answer
        self.metadata_frame = metadata_frame
        self.batcher = batcher
        self.guard = guard  # None: the process-wide guard when the server starts
        self._serving = current() if guard is None else guard
        self._connections = 0  # connections being served (their handler runs)

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
        guard = self._serving = current() if self.guard is None else self.guard
        if self.batcher.max_queued is None:
            self.batcher.max_queued = guard.max_queued
        batcher = asyncio.create_task(self.batcher.run(), name="batcher")
        try:
            async with ws_server.serve(
                self._handle,
                host,
                port,
                compression=None,
                max_size=guard.max_message_bytes,
                max_queue=MAX_QUEUED_FRAMES,
                process_request=functools.partial(_admit, guard, lambda: self._connections),
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
        limit = self._serving.max_connections
        if self._connections >= limit:  # upgrades that passed _admit together: the handler count is exact
            reason = f"busy: {limit} connections (--max-connections)"
            await connection.close(code=CloseCode.TRY_AGAIN_LATER, reason=reason)
            return
        self._connections += 1
        try:
            await self._serve_connection(connection)
        finally:
            self._connections -= 1

    async def _serve_connection(self, connection: ws_server.ServerConnection) -> None:
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
            except ServerBusy as error:
                logger.warning("refused a request: %s", error)
                await _fail(connection, f"ServerBusy: {error}", "Server busy")
                return
            except Exception as error:  # the traceback stays here (once: a failed batch's, the batcher logged it)
                line = error_line(error)
                logger.error("cannot answer a request: %s", line, exc_info=None if logged(error) else error)
                await _fail(connection, line, "Internal server error")
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


def _admit(
    guard: Guard, connections: Callable[[], int], connection: ws_server.ServerConnection, request: ws_server.Request
) -> ws_server.Response | None:
    """At the upgrade: ``/healthz`` answers; a request without the token, or beyond ``max_connections``, is
    refused with one line; anything else goes on to the websocket."""
    if request.path == "/healthz":
        return connection.respond(http.HTTPStatus.OK, "OK\n")
    if not guard.admits_header(request.headers.get(AUTHORIZATION)):
        logger.warning("refused a connection from %s: no valid token", connection.remote_address)
        return connection.respond(http.HTTPStatus.UNAUTHORIZED, f"{UNAUTHORIZED}\n")
    if connections() >= guard.max_connections:
        return connection.respond(
            http.HTTPStatus.SERVICE_UNAVAILABLE,
            f"Busy: this server serves {guard.max_connections} connections at most (--max-connections)\n",
        )
    return None
