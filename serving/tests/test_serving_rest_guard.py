"""What a stranger can do to our REST server (deploy.py's protocol), over real HTTP on 127.0.0.1 (uvicorn, as
``rest.serve`` runs it): bodies over the message bound, more connections than allowed, no token or a wrong one; and
errors answered in one line."""

from __future__ import annotations

import asyncio
import http.client
import json
import socket
import threading
from contextlib import contextmanager

import pytest

pytest.importorskip("fastapi")
uvicorn = pytest.importorskip("uvicorn")

from conflictbench_serving import guard as guards  # noqa: E402 (after the extra's check)
from conflictbench_serving import rest  # noqa: E402
from conflictbench_serving.guard import Guard  # noqa: E402

TIMEOUT_S = 10


class Doubler:
    metadata = {"hosted": "doubler"}

    def __init__(self, fail: bool = False):
        self.fail = fail

    def infer_batch(self, rows):
        if self.fail:
            raise RuntimeError("the model broke\non line two")
        return [2 * row for row in rows]


def parse(body: bytes):
    try:
        return json.loads(body)["n"], False
    except (ValueError, KeyError, TypeError) as error:
        raise rest.InvalidRequest(f"not a request: {error}") from None


@contextmanager
def serving(guard: Guard | None = None, fail: bool = False, **settings):
    """``rest.serve``'s app and uvicorn settings on a free port, in a thread (uvicorn leaves signals alone there)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    app = rest.build_app(Doubler(fail), 1, parse, "doubler", guard)
    limits = rest.limits(guards.current() if guard is None else guard, **settings)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False, **limits))
    thread = threading.Thread(target=asyncio.run, args=(server.serve(sockets=[sock]),), daemon=True)
    thread.start()
    for _ in range(500):
        if server.started:
            break
        threading.Event().wait(0.01)
    try:
        yield sock.getsockname()[1]
    finally:
        server.should_exit = True
        thread.join(TIMEOUT_S)


def request(port: int, method: str, path: str, body=None, headers=None, conn=None) -> tuple[int, dict]:
    conn = conn or http.client.HTTPConnection("127.0.0.1", port, timeout=TIMEOUT_S)
    conn.request(method, path, body, headers or {}, encode_chunked="Transfer-Encoding" in (headers or {}))
    response = conn.getresponse()
    return response.status, json.loads(response.read())


def test_a_body_over_the_message_bound_is_refused_413_before_it_is_read_whole():
    limit = guards.current().max_message_bytes
    padded = b'{"n": 1}' + b" " * limit  # valid JSON, one byte more than the bound allows
    with serving() as port:
        status, answer = request(port, "POST", "/act", padded)
        assert (status, answer) == (413, {"error": rest._too_large(limit)})
        assert request(port, "POST", "/act", b'{"n": 21}') == (200, 42)


def test_a_streamed_body_is_counted_as_it_comes():
    def chunks():
        yield b'{"n": 1}'
        for _ in range(10):
            yield b" " * 200

    with serving(Guard(max_message_bytes=1000)) as port:
        status, answer = request(port, "POST", "/act", chunks(), {"Transfer-Encoding": "chunked"})
        assert status == 413 and answer["error"] == rest._too_large(1000)


def test_connections_beyond_max_connections_are_answered_503():
    with serving(Guard(max_connections=2, max_queued=2)) as port:
        held = [http.client.HTTPConnection("127.0.0.1", port, timeout=TIMEOUT_S) for _ in range(2)]
        try:
            for conn in held:  # two keep-alive connections, open
                assert request(port, "GET", "/metadata", conn=conn)[0] == 200
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=TIMEOUT_S)
            conn.request("GET", "/metadata")
            assert conn.getresponse().status == 503
            assert request(port, "POST", "/act", b'{"n": 2}', conn=held[0]) == (200, 4)
        finally:
            for conn in held:
                conn.close()


@pytest.mark.parametrize("header", [None, "Api-Key wrong", "Bearer s3cret"], ids=["missing", "wrong", "scheme"])
def test_every_request_but_healthz_needs_the_token(header):
    headers = {"Authorization": header} if header else {}
    with serving(Guard(token="s3cret")) as port:
        for method, path, body in (("POST", "/act", b'{"n": 1}'), ("GET", "/metadata", None), ("GET", "/x", None)):
            status, answer = request(port, method, path, body, headers)
            assert status == 401 and answer["error"].startswith("Unauthorized") and "s3cret" not in answer["error"]
        assert request(port, "GET", "/healthz") == (200, {"status": "ok"})
        right = {"Authorization": "Api-Key s3cret"}
        assert request(port, "POST", "/act", b'{"n": 1}', right) == (200, 2)
        assert request(port, "GET", "/metadata", None, right)[1]["hosted"] == "doubler"


def test_errors_are_one_line():
    with serving(fail=True) as port:
        assert request(port, "POST", "/act", b'{"n": 1}') == (
            500,
            {"error": "RuntimeError: the model broke on line two"},
        )
        status, answer = request(port, "POST", "/act", b'{"m":\n 1}')
        assert status == 400 and "\n" not in answer["error"]


def test_connections_that_send_no_request_are_closed_so_they_cannot_hold_every_slot():
    deadline = 0.5  # rest.FIRST_REQUEST_S (5 s) in a real server
    right = {"Authorization": "Api-Key s3cret"}
    with serving(Guard(token="s3cret", max_connections=4, max_queued=4), first_request_s=deadline) as port:
        strangers = [socket.create_connection(("127.0.0.1", port), timeout=TIMEOUT_S) for _ in range(5)]
        try:
            strangers[-1].sendall(b"POST /act HTTP/1.1\r\nHost: x\r\n")  # headers begun, never finished
            threading.Event().wait(deadline + 1.0)
            for stranger in strangers:  # each closed by the server: reading gives end of file at once
                assert stranger.recv(1024) == b""
            assert request(port, "POST", "/act", b'{"n": 3}', right) == (200, 6)
        finally:
            for stranger in strangers:
                stranger.close()


def test_a_failed_model_call_leaves_its_traceback_in_the_server_log(caplog):
    with serving(fail=True) as port:
        assert request(port, "POST", "/act", b'{"n": 1}')[0] == 500
    assert caplog.text.count("Traceback") == 1 and "the model broke" in caplog.text
