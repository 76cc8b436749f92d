"""What a stranger can do to our websocket server, over real connections on 127.0.0.1: frames over the message bound,
more connections than allowed, a flooded queue, no token or a wrong one; and errors answered in one line."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
import urllib.request
from pathlib import Path

import pytest
from test_serving_websocket import running  # noqa: I001 (the suite's server-in-a-thread helper)
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from conflictbench_serving import guard as guards
from conflictbench_serving.batching import Batcher, ServerBusy
from conflictbench_serving.guard import Guard
from conflictbench_serving.msgpack_numpy import packb, unpackb
from conflictbench_serving.websocket import WebsocketPolicyServer

TIMEOUT_S = 10
#: Frames the server may read ahead on one connection, as its docs promise (a literal: raising the server's constant
#: to websockets' default 16 must fail the test, not move its bound).
READ_AHEAD = 2


def _server(guard: Guard | None = None, fail: bool = False) -> WebsocketPolicyServer:
    """Answers a frame with its length (through the batcher); ``fail``: every request raises, with a message
    of two lines."""

    def infer(rows):
        if fail:
            raise RuntimeError("the model broke\non line two")
        return rows

    async def answer(frame, session):
        length, _ = await server.batcher.submit(len(frame))
        return packb({"length": length})

    server = WebsocketPolicyServer(answer, packb({"hosted": "lengths"}), Batcher(infer, 2, False), guard=guard)
    return server


def _ask(url: str, frame: bytes, **options):
    with connect(url, proxy=None, open_timeout=TIMEOUT_S, max_size=None, **options) as client:
        client.recv(timeout=TIMEOUT_S)
        client.send(frame)
        return client.recv(timeout=TIMEOUT_S)


def test_a_frame_over_the_message_bound_closes_its_connection_with_1009_and_others_go_on():
    limit = guards.current().max_message_bytes
    with running(_server()) as port:
        url = f"ws://127.0.0.1:{port}"
        with pytest.raises(ConnectionClosed) as closed:
            _ask(url, b"x" * (limit + 1))
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
        assert unpackb(_ask(url, b"x" * 1000)) == {"length": 1000}


def test_connections_beyond_max_connections_are_refused_in_one_line_until_one_closes():
    with running(_server(Guard(max_connections=2, max_queued=4))) as port:
        url = f"ws://127.0.0.1:{port}"
        with connect(url, proxy=None, open_timeout=TIMEOUT_S) as first, connect(url, proxy=None) as second:
            first.recv(timeout=TIMEOUT_S), second.recv(timeout=TIMEOUT_S)
            with pytest.raises(InvalidStatus) as refused:
                connect(url, proxy=None, open_timeout=TIMEOUT_S)
            assert refused.value.response.status_code == 503
            busy = b"Busy: this server serves 2 connections at most (--max-connections)\n"
            assert refused.value.response.body == busy
            first.close()
            for _ in range(100):  # the server sees the close a moment later
                try:
                    assert unpackb(_ask(url, b"abc")) == {"length": 3}
                    break
                except InvalidStatus:
                    threading.Event().wait(0.05)
            else:
                pytest.fail("a connection was still refused after one closed")


def test_a_full_queue_answers_busy_and_never_grows():
    entered, release = threading.Event(), threading.Event()

    def held(rows):
        entered.set()
        release.wait(TIMEOUT_S)
        return rows

    async def flood() -> tuple[list, int]:
        batcher = Batcher(held, 1, False, max_queued=3)
        runner = asyncio.create_task(batcher.run())
        try:
            first = asyncio.create_task(batcher.submit(0))
            while not entered.is_set():  # the model holds the first request; the next ones queue
                await asyncio.sleep(0.01)
            waiting = [asyncio.create_task(batcher.submit(i)) for i in range(1, 4)]
            await asyncio.sleep(0)
            with pytest.raises(ServerBusy, match="3 requests already wait for the model \\(max_queued\\)"):
                await batcher.submit(99)
            queued = batcher.queued
            release.set()
            return await asyncio.gather(first, *waiting), queued
        finally:
            release.set()
            runner.cancel()
            batcher.shutdown()

    answers, queued = asyncio.run(flood())
    assert queued == 3 and [answer for answer, _ in answers] == [0, 1, 2, 3]


def test_an_unexpected_error_is_answered_in_one_line_not_a_traceback(caplog):
    with running(_server(fail=True)) as port:
        with connect(f"ws://127.0.0.1:{port}", proxy=None, open_timeout=TIMEOUT_S) as client:
            client.recv(timeout=TIMEOUT_S)
            client.send(b"abc")
            answer = client.recv(timeout=TIMEOUT_S)
    assert answer == "RuntimeError: the model broke on line two"
    assert caplog.text.count("Traceback") == 1  # in the server's log, once (the batcher's)


@pytest.mark.parametrize("header", [None, "Api-Key wrong", "Bearer s3cret"], ids=["missing", "wrong", "scheme"])
def test_a_connection_without_the_token_is_refused_401_and_healthz_still_answers(header):
    with running(_server(Guard(token="s3cret"))) as port:
        url = f"ws://127.0.0.1:{port}"
        headers = {"Authorization": header} if header else None
        with pytest.raises(InvalidStatus) as refused:
            connect(url, proxy=None, open_timeout=TIMEOUT_S, additional_headers=headers)
        assert refused.value.response.status_code == 401
        body = refused.value.response.body.decode()
        assert body.startswith("Unauthorized") and body.count("\n") == 1 and "s3cret" not in body
        assert unpackb(_ask(url, b"abcd", additional_headers={"Authorization": "Api-Key s3cret"})) == {"length": 4}
        assert urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=TIMEOUT_S).read() == b"OK\n"


def test_a_server_given_no_guard_uses_the_process_wide_one():
    before = guards._current
    try:
        guards.configure(token="from-configure")
        with running(_server()) as port, pytest.raises(InvalidStatus):
            connect(f"ws://127.0.0.1:{port}", proxy=None, open_timeout=TIMEOUT_S)
    finally:
        guards._current = before


def _bytes_loopback_tcp_may_hold(sending: socket.socket) -> int:
    """What the kernel may hold between a sender and a peer that stopped reading: the sender's send buffer and the
    peer's receive buffer, which Linux grows up to ``tcp_rmem``'s maximum (32 MiB on the CI machine: 9 frames of
    6 MiB were once taken where a fixed bound of 8 assumed less)."""
    try:
        receive_max = int(Path("/proc/sys/net/ipv4/tcp_rmem").read_text().split()[2])
    except (OSError, IndexError, ValueError):
        receive_max = 6 * 2**20  # Linux's default maximum
    return sending.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF) + receive_max


def test_a_peer_that_sends_without_reading_is_held_back_not_buffered():
    """Frames sent while the model holds the first are not read ahead without bound (websockets buffers 16 by
    default: 16 x max_message_bytes per connection); TCP holds the sender back instead. The sender may finish
    one frame in the model, READ_AHEAD read ahead, one completed and one half-read as reading pauses, and
    what the kernel's buffers hold; it sends 4 more, all of which websockets' default would take."""
    frame = 6 * 2**20
    release = threading.Event()

    def held(rows):
        release.wait(TIMEOUT_S)
        return rows

    async def answer(frame, session):
        length, _ = await server.batcher.submit(len(frame))
        return packb({"length": length})

    server = WebsocketPolicyServer(answer, packb({}), Batcher(held, 1, False))
    sent = []
    with running(server) as port, connect(f"ws://127.0.0.1:{port}", proxy=None, max_size=None) as client:
        client.recv(timeout=TIMEOUT_S)
        client.socket.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 2**16)
        bound = 1 + READ_AHEAD + 2 + math.ceil(_bytes_loopback_tcp_may_hold(client.socket) / frame)

        def flood():
            for _ in range(bound + 4):
                client.send(b"x" * frame)
                sent.append(1)

        sender = threading.Thread(target=flood, daemon=True)
        sender.start()
        sender.join(2)
        in_flight = len(sent)
        release.set()
        sender.join(TIMEOUT_S)
    assert in_flight <= bound, f"{in_flight} frames of 6 MiB were taken while the model held the first (bound {bound})"
