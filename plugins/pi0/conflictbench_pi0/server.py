"""A websocket server speaking openpi's protocol that batches the requests of concurrent connections.

openpi's own ``openpi-server`` runs one ``infer()`` per request. Here every connection queues its
validated request with a future, and one batcher task hands everything queued (up to ``max_batch``)
to ``backend.infer_batch`` in a single worker thread, so model calls never overlap and N simulator
workers keep one model busy with batches of up to N. With ``fixed_shape`` (what ``serve`` and the
command use) each call is padded to exactly ``max_batch`` rows: float rounding depends on a batch's
shape, and which requests share a call depends on timing, so only a fixed shape keeps every episode's
actions reproducible. The metadata frame says ``max_batch`` and ``fixed_shape``.

The wire protocol is openpi's (see :mod:`conflictbench_pi0.protocol`): the packed metadata first on
every connection, one binary frame per request and per reply (``{"actions": chunk, "server_timing":
{"infer_ms", "batch_size", "prev_total_ms"}}``; ``batch_size`` is ours), and on failure a text frame
with the error followed by close code 1011. A malformed request fails only its own connection; a
failing model call fails every request of that batch. ``GET /healthz`` answers ``OK``; the port is
bound only once the caller has loaded the backend, so a ``/healthz`` answer means ready.

This module imports neither conflictbench nor torch: it runs in the model environment.
"""

from __future__ import annotations

import asyncio
import http
import logging
import signal
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import websockets
import websockets.asyncio.server as ws_server
from websockets.frames import CloseCode

from conflictbench_pi0 import protocol
from conflictbench_pi0.protocol import InvalidRequest, validate_request

logger = logging.getLogger(__name__)


class Backend(Protocol):
    """What the server needs of a model (``backend.PiBackend`` is the real one)."""

    metadata: dict

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]: ...


class ServerStopping(Exception):
    """The server stopped before this request's batch ran."""


@dataclass
class _Pending:
    request: dict
    reply: asyncio.Future = field(default_factory=lambda: asyncio.get_running_loop().create_future())


class BatchingPolicyServer:
    """Serves ``backend`` to any number of connections, one model call at a time, batching what waits."""

    def __init__(self, backend: Backend, max_batch: int = 32, fixed_shape: bool = False) -> None:
        if max_batch < 1:
            raise ValueError(f"max_batch must be at least 1, got {max_batch}")
        self.backend = backend
        self.max_batch = max_batch
        self.fixed_shape = fixed_shape
        """Every model call gets exactly ``max_batch`` rows (the batch padded with copies of its last
        request): a request's actions then never depend on how many others shared its call."""
        self._metadata_frame = protocol.packb({**backend.metadata, "max_batch": max_batch, "fixed_shape": fixed_shape})
        self._queue: asyncio.Queue[_Pending] = asyncio.Queue()
        # One thread: model calls never overlap, and torch sees the same thread every time.
        self._model_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pi-model")

    @property
    def queued(self) -> int:
        """Requests waiting for the next batch."""
        return self._queue.qsize()

    async def run(
        self,
        host: str,
        port: int,
        stop: asyncio.Event,
        on_ready: Callable[[str, int], None] | None = None,
    ) -> None:
        """Serve on ``host:port`` (``port`` 0: any free one) until ``stop`` is set.

        ``on_ready(host, port)`` is called once the socket is bound, with the port actually bound."""
        batcher = asyncio.create_task(self._run_batches(), name="pi-batcher")
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
            # A model call still running finishes in its thread; nothing waits for its result.
            self._model_thread.shutdown(wait=False, cancel_futures=True)

    async def _handle(self, connection: ws_server.ServerConnection) -> None:
        await connection.send(self._metadata_frame)
        previous_total_ms = None
        while True:
            try:
                frame = await connection.recv()
            except websockets.ConnectionClosed:
                return
            started = time.monotonic()
            try:
                if isinstance(frame, str):
                    raise InvalidRequest("a request must be a binary frame, got a text frame")
                try:
                    request = protocol.unpackb(frame)
                except Exception as error:
                    raise InvalidRequest(f"not an openpi msgpack frame: {error}") from error
                pending = _Pending(validate_request(request))
                self._queue.put_nowait(pending)
                actions, timing = await pending.reply
            except InvalidRequest as error:
                await _fail(connection, f"invalid request: {error}", "Invalid request")
                return
            except ServerStopping:
                return
            except Exception as error:
                await _fail(connection, _traceback_text(error), "Internal server error")
                return
            if previous_total_ms is not None:
                timing = {**timing, "prev_total_ms": previous_total_ms}
            try:
                await connection.send(protocol.packb({protocol.ACTIONS: actions, "server_timing": timing}))
            except websockets.ConnectionClosed:
                return
            previous_total_ms = (time.monotonic() - started) * 1000

    async def _run_batches(self) -> None:
        loop = asyncio.get_running_loop()
        batch: list[_Pending] = []
        try:
            while True:
                batch = [await self._queue.get()]
                while len(batch) < self.max_batch and not self._queue.empty():
                    batch.append(self._queue.get_nowait())
                requests = [pending.request for pending in batch]
                if self.fixed_shape:
                    requests += [requests[-1]] * (self.max_batch - len(requests))
                started = time.monotonic()
                try:
                    chunks = await loop.run_in_executor(self._model_thread, self.backend.infer_batch, requests)
                    if len(chunks) != len(requests):
                        raise RuntimeError(f"infer_batch returned {len(chunks)} chunks for {len(requests)} requests")
                    chunks = chunks[: len(batch)]
                except Exception as error:
                    logger.error("inference failed for a batch of %d: %s", len(batch), error)
                    for pending in batch:
                        _settle(pending, error=error)
                else:
                    timing = {"infer_ms": (time.monotonic() - started) * 1000, "batch_size": len(batch)}
                    logger.debug("batch of %d in %.1f ms", len(batch), timing["infer_ms"])
                    for pending, chunk in zip(batch, chunks, strict=True):
                        _settle(pending, result=(chunk, timing))
                batch = []
        finally:
            stopping = ServerStopping()
            for pending in batch:
                _settle(pending, error=stopping)
            while not self._queue.empty():
                _settle(self._queue.get_nowait(), error=stopping)


def _settle(pending: _Pending, result: Any = None, error: BaseException | None = None) -> None:
    if pending.reply.done():
        return
    if error is not None:
        pending.reply.set_exception(error)
    else:
        pending.reply.set_result(result)


def _traceback_text(error: BaseException) -> str:
    return "".join(traceback.format_exception(error))


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

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, stop.set)
        await BatchingPolicyServer(backend, max_batch, fixed_shape).run(host, port, stop, on_ready)

    asyncio.run(main())
