"""One model, many connections: every request waiting while a model call runs joins the next call.

A server's connection handlers ``await batcher.submit(request)``; :meth:`Batcher.run` hands everything
queued (up to ``max_batch``) to ``infer_batch`` in a single worker thread, so model calls never overlap
and N simulator workers keep one model busy with batches of up to N. With ``fixed_shape`` every call is
padded to exactly ``max_batch`` rows (copies of its last request): float rounding depends on a batch's
shape, and which requests share a call depends on timing, so only a fixed shape keeps every episode's
actions reproducible. A failing call fails every request of its batch; nothing else.

The queue is bounded (``max_queued``, the guard's): a request that finds it full is answered at once with
:class:`ServerBusy`, so a peer that floods the server cannot make it hold requests without end. Our clients keep
one request in flight per connection, so a queue at least as long as the connections allowed never fills.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from .guard import current

logger = logging.getLogger(__name__)

InferBatch = Callable[[list[Any]], list[Any]]


#: Set on a model call's error once the batcher has logged its traceback, so a server logs it no second time.
_LOGGED = "_conflictbench_logged"


def logged(error: BaseException) -> bool:
    """Whether ``error`` is a failed model call whose traceback the batcher has already logged."""
    return bool(getattr(error, _LOGGED, False))


class ServerStopping(Exception):
    """The server stopped before this request's batch ran."""


class ServerBusy(Exception):
    """The queue is full: this request was not queued (the peer may send it again later)."""


@dataclass
class _Pending:
    request: Any
    reply: asyncio.Future = field(default_factory=lambda: asyncio.get_running_loop().create_future())


class Batcher:
    """Queues requests and runs ``infer_batch`` on batches of them, one call at a time."""

    def __init__(
        self,
        infer_batch: InferBatch,
        max_batch: int,
        fixed_shape: bool,
        name: str = "model",
        max_queued: int | None = None,
    ) -> None:
        if max_batch < 1:
            raise ValueError(f"max_batch must be at least 1, got {max_batch}")
        self.infer_batch = infer_batch
        self.max_batch = max_batch
        self.fixed_shape = fixed_shape
        # None: the process-wide guard's (read when a request comes); a server sets its own guard's at run
        self.max_queued = max_queued
        self._queue: asyncio.Queue[_Pending] = asyncio.Queue()
        self._stopped = False
        # One thread: model calls never overlap, and torch sees the same thread every time.
        self._model_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{name}-model")

    @property
    def queued(self) -> int:
        """Requests waiting for the next batch."""
        return self._queue.qsize()

    async def submit(self, request: Any) -> tuple[Any, dict]:
        """The model's answer to ``request`` and the call's timing (``infer_ms``, ``batch_size``); raises
        what the call raised, :class:`ServerBusy` when ``max_queued`` requests already wait, or
        :class:`ServerStopping` (also for a request that arrives once it has stopped: a connection still closing
        may deliver one, and nothing would ever answer it)."""
        if self._stopped:
            raise ServerStopping()
        limit = self.max_queued if self.max_queued is not None else current().max_queued
        if self._queue.qsize() >= limit:
            raise ServerBusy(f"the server is busy: {limit} requests already wait for the model (max_queued)")
        pending = _Pending(request)
        self._queue.put_nowait(pending)
        return await pending.reply

    async def run(self) -> None:
        """Serve batches until cancelled; requests still waiting then fail with :class:`ServerStopping`."""
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
                    answers = await loop.run_in_executor(self._model_thread, self.infer_batch, requests)
                    if len(answers) != len(requests):
                        raise RuntimeError(f"infer_batch returned {len(answers)} answers for {len(requests)} requests")
                except Exception as error:
                    # the traceback stays here, once per batch; each request's peer gets one line
                    logger.error("inference failed for a batch of %d: %s", len(batch), error, exc_info=error)
                    setattr(error, _LOGGED, True)
                    for pending in batch:
                        _settle(pending, error=error)
                else:
                    timing = {"infer_ms": (time.monotonic() - started) * 1000, "batch_size": len(batch)}
                    logger.debug("batch of %d in %.1f ms", len(batch), timing["infer_ms"])
                    for pending, answer in zip(batch, answers[: len(batch)], strict=True):
                        _settle(pending, result=(answer, timing))
                batch = []
        finally:
            self._stopped = True
            stopping = ServerStopping()
            for pending in batch:
                _settle(pending, error=stopping)
            while not self._queue.empty():
                _settle(self._queue.get_nowait(), error=stopping)

    def shutdown(self) -> None:
        """Let go of the model thread: queued calls are cancelled; one still running finishes in its thread
        (the interpreter waits for it at exit)."""
        self._model_thread.shutdown(wait=False, cancel_futures=True)


def _settle(pending: _Pending, result: Any = None, error: BaseException | None = None) -> None:
    if pending.reply.done():
        return
    if error is not None:
        pending.reply.set_exception(error)
    else:
        pending.reply.set_result(result)
