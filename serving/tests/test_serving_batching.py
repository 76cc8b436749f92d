"""The batcher on its own: fixed-shape padding, failures confined to their batch, a clean stop."""

from __future__ import annotations

import asyncio
import threading

import pytest

from conflictbench_serving.batching import Batcher, ServerStopping


class Recorder:
    """infer_batch that records each call's rows and answers each row with (row, call number)."""

    def __init__(self, fail_on=None, release: threading.Event | None = None):
        self.calls: list[list] = []
        self.fail_on = fail_on
        self.release = release
        self.entered = threading.Event()  # a call has begun (and holds the model thread until released)

    def __call__(self, requests: list) -> list:
        self.entered.set()
        if self.release is not None:
            self.release.wait(5)
        self.calls.append(list(requests))
        if self.fail_on in requests:
            raise RuntimeError(f"failed on {self.fail_on}")
        return [(row, len(self.calls)) for row in requests]


async def _until(condition, seconds: float = 5.0) -> None:
    """Yield to the event loop until ``condition()`` holds; fail after ``seconds`` (a wait on the event
    itself, not on a guess of how long it takes)."""
    deadline = asyncio.get_running_loop().time() + seconds
    while not condition():
        assert asyncio.get_running_loop().time() < deadline, f"the awaited event did not come within {seconds} s"
        await asyncio.sleep(0.001)


async def _with_batcher(batcher: Batcher, body):
    runner = asyncio.create_task(batcher.run())
    try:
        return await body()
    finally:
        runner.cancel()
        await asyncio.gather(runner, return_exceptions=True)
        batcher.shutdown()


def test_waiting_requests_share_a_call_padded_to_the_fixed_shape():
    release = threading.Event()
    model = Recorder(release=release)
    batcher = Batcher(model, max_batch=4, fixed_shape=True)

    async def body():
        first = asyncio.create_task(batcher.submit("a"))
        await _until(model.entered.is_set)  # "a" is in the model call (held), "b" and "c" wait together
        rest = [asyncio.create_task(batcher.submit(r)) for r in "bc"]
        await _until(lambda: batcher.queued == 2)
        release.set()
        return await asyncio.gather(first, *rest)

    answers = asyncio.run(_with_batcher(batcher, body))
    assert model.calls == [["a", "a", "a", "a"], ["b", "c", "c", "c"]]
    assert [answer for answer, _ in answers] == [("a", 1), ("b", 2), ("c", 2)]
    assert [timing["batch_size"] for _, timing in answers] == [1, 2, 2]


def test_without_fixed_shape_a_call_has_only_the_waiting_rows():
    model = Recorder()
    batcher = Batcher(model, max_batch=4, fixed_shape=False)
    asyncio.run(_with_batcher(batcher, lambda: batcher.submit("a")))
    assert model.calls == [["a"]]


def test_a_failing_call_fails_its_batch_only():
    model = Recorder(fail_on="bad")
    batcher = Batcher(model, max_batch=2, fixed_shape=False)

    async def body():
        with pytest.raises(RuntimeError, match="failed on bad"):
            await batcher.submit("bad")
        return await batcher.submit("good")

    answer, _ = asyncio.run(_with_batcher(batcher, body))
    assert answer == ("good", 2)


def test_a_wrong_number_of_answers_is_an_error_not_a_misrouted_reply():
    batcher = Batcher(lambda requests: requests[:-1], max_batch=1, fixed_shape=False)

    async def body():
        with pytest.raises(RuntimeError, match="returned 0 answers for 1 requests"):
            await batcher.submit("a")

    asyncio.run(_with_batcher(batcher, body))


def test_requests_still_waiting_when_it_stops_are_told_so():
    release = threading.Event()
    model = Recorder(release=release)
    batcher = Batcher(model, max_batch=1, fixed_shape=False)

    async def body():
        runner = asyncio.create_task(batcher.run())
        running = asyncio.create_task(batcher.submit("a"))
        await _until(model.entered.is_set)  # "a" is in the model call, held there
        waiting = asyncio.create_task(batcher.submit("b"))
        await _until(lambda: batcher.queued == 1)
        runner.cancel()
        await asyncio.gather(runner, return_exceptions=True)
        release.set()
        batcher.shutdown()
        return await asyncio.gather(running, waiting, return_exceptions=True)

    outcomes = asyncio.run(body())
    assert all(isinstance(outcome, ServerStopping) for outcome in outcomes)


def test_max_batch_must_be_positive():
    with pytest.raises(ValueError, match="at least 1"):
        Batcher(Recorder(), max_batch=0, fixed_shape=True)


def test_a_request_arriving_after_the_stop_is_told_so_at_once():
    """A connection still closing may deliver one more request; nothing would ever answer it."""
    batcher = Batcher(Recorder(), max_batch=1, fixed_shape=False)

    async def body():
        runner = asyncio.create_task(batcher.run())
        await asyncio.sleep(0)  # one turn of the loop: the runner starts (a cancelled task never run has no finally)
        runner.cancel()
        await asyncio.gather(runner, return_exceptions=True)
        batcher.shutdown()
        with pytest.raises(ServerStopping):
            await asyncio.wait_for(batcher.submit("late"), timeout=2)

    asyncio.run(body())
