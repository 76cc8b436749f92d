"""What a stranger can do to our ZeroMQ server (GR00T's protocol), over real REQ sockets on 127.0.0.1: messages over
the message bound, a flood of requests, no token or a wrong one (ping included); and errors answered in one line."""

from __future__ import annotations

import threading
from contextlib import contextmanager

import pytest
import zmq
from test_serving_websocket import running  # the suite's server-in-a-thread helper (any of our servers)

from conflictbench_serving import guard as guards
from conflictbench_serving.batching import Batcher
from conflictbench_serving.guard import Guard
from conflictbench_serving.zeromq import ZmqPolicyServer, endpoint_request, packb, unpackb

TIMEOUT_MS = 10_000


class LengthServer(ZmqPolicyServer):
    """Answers ``get_action`` with the length of ``data["text"]`` (through the batcher, which ``hold`` can hold)."""

    def __init__(self, guard: Guard | None = None, fail: bool = False):
        self.hold, self.entered = threading.Event(), threading.Event()
        self.hold.set()

        def infer(rows):
            self.entered.set()
            self.hold.wait(10)
            if fail:
                raise RuntimeError("the model broke\non line two")
            return rows

        super().__init__(Batcher(infer, 1, False), {"hosted": "lengths"}, guard=guard)

    async def get_action(self, data):
        answer, _ = await self.batcher.submit(len(data.get("text", "")))
        return {"length": answer}


@contextmanager
def client(port: int, timeout_ms: int = TIMEOUT_MS):
    context = zmq.Context()
    socket = context.socket(zmq.REQ)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, timeout_ms)
    socket.connect(f"tcp://127.0.0.1:{port}")

    def call(request):
        socket.send(request if isinstance(request, bytes) else packb(request))
        return unpackb(socket.recv())

    try:
        yield call
    finally:
        socket.close()
        context.term()


def test_a_message_over_the_bound_is_dropped_unread_and_others_are_answered():
    limit = guards.current().max_message_bytes
    with running(LengthServer()) as port:
        with client(port, timeout_ms=2000) as call, pytest.raises(zmq.Again):
            call({"endpoint": "get_action", "data": {"text": "x" * limit}})  # never answered: the peer is dropped
        with client(port) as call:
            assert call({"endpoint": "get_action", "data": {"text": "abc"}}) == {"length": 3}


@pytest.mark.parametrize("token", [None, "wrong", 7], ids=["missing", "wrong", "not-text"])
def test_every_request_needs_the_token_ping_included(token):
    with running(LengthServer(Guard(token="s3cret"))) as port, client(port) as call:
        for endpoint in ("ping", "conflictbench_metadata", "get_action"):
            request = {"endpoint": endpoint, "data": {"text": "abc"}}
            if token is not None:
                request["api_token"] = token
            assert call(request) == {"error": "Unauthorized: Invalid API token"}
        assert call(endpoint_request("ping", "s3cret"))["status"] == "ok"
        assert call({"endpoint": "get_action", "data": {"text": "abc"}, "api_token": "s3cret"}) == {"length": 3}


def test_a_flood_is_answered_busy_at_once_and_the_held_request_still_gets_its_answer():
    server = LengthServer(Guard(max_connections=1, max_queued=1))
    server.hold.clear()
    with running(server) as port, client(port) as first, client(port) as second:
        done = {}
        waiting = threading.Thread(target=lambda: done.update(first=first({"data": {"text": "held"}})))
        waiting.start()
        assert server.entered.wait(10)
        assert second({"data": {"text": "more"}}) == {"error": "ServerBusy: 1 requests are being answered (max_queued)"}
        server.hold.set()
        waiting.join(10)
        assert done["first"] == {"length": 4}


def test_errors_are_one_line():
    with running(LengthServer(fail=True)) as port, client(port) as call:
        assert call({"data": {"text": "abc"}}) == {"error": "RuntimeError: the model broke on line two"}
        assert call(b"\xc1")["error"].count("\n") == 0  # not msgpack at all


def test_a_server_given_no_guard_uses_the_process_wide_one():
    before = guards._current
    try:
        guards.configure(token="from-configure")
        with running(LengthServer()) as port, client(port) as call:
            assert call(endpoint_request("ping")) == {"error": "Unauthorized: Invalid API token"}
            assert call(endpoint_request("ping", "from-configure"))["status"] == "ok"
    finally:
        guards._current = before


@contextmanager
def dealer(port: int):
    """A DEALER socket: it sends whatever frames it likes (a REQ socket sends its delimiter and one message)."""
    context = zmq.Context()
    socket = context.socket(zmq.DEALER)
    socket.setsockopt(zmq.LINGER, 0)
    socket.connect(f"tcp://127.0.0.1:{port}")
    try:
        yield socket
    finally:
        socket.close()
        context.term()


def test_a_message_of_more_frames_than_a_request_is_dropped_and_never_echoed():
    # Each frame is under the bound (ZeroMQ's MAXMSGSIZE is per frame), the message is 300 times it; the server
    # used to read it whole and send 299 frames of it back as the reply's envelope.
    limit = 10_000
    frames = [b""] + [b"x" * (limit - 1)] * 298 + [packb(endpoint_request("ping"))]
    with running(LengthServer(Guard(max_message_bytes=limit))) as port:
        with dealer(port) as stranger:
            stranger.send_multipart(frames)
            assert not stranger.poll(1000), "the server answered (and echoed the frames)"
            stranger.send_multipart([b"", b"extra", packb(endpoint_request("ping"))])  # small, but one frame too many
            assert not stranger.poll(500)
            stranger.send_multipart([b"", packb(endpoint_request("ping"))])  # what a REQ socket sends: answered
            assert stranger.poll(TIMEOUT_MS)
            assert unpackb(stranger.recv_multipart()[-1])["status"] == "ok"
        with client(port) as call:
            assert call({"endpoint": "get_action", "data": {"text": "abc"}}) == {"length": 3}


def test_the_token_is_checked_before_any_array_is_decoded():
    unsafe = {"__ndarray_class__": True, "as_npy": b"\x93NUMPY not an array"}
    with running(LengthServer(Guard(token="s3cret"))) as port, client(port) as call:
        stranger = {"endpoint": "get_action", "data": {"image": unsafe}}
        assert call(stranger) == {"error": "Unauthorized: Invalid API token"}
        answer = call({"endpoint": "get_action", "data": {"image": unsafe}, "api_token": "s3cret"})
        assert answer["error"].startswith("UnsafeArray: not .npy data")


def test_a_failed_model_call_leaves_its_traceback_in_the_server_log(caplog):
    with running(LengthServer(fail=True)) as port, client(port) as call:
        assert call({"data": {"text": "abc"}})["error"].startswith("RuntimeError")
    assert caplog.text.count("Traceback") == 1 and "the model broke" in caplog.text
