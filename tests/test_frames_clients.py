"""The run's transports against real servers on 127.0.0.1: they send the server's token (a refused one is a
PermissionError, which the client never retries: the run stops in one line), bound what they send and read by
max_message_bytes, and still read the traceback frames openpi's own servers send."""

from __future__ import annotations

import asyncio
import http.server
import socket
import threading
import time
from contextlib import contextmanager

import pytest

from conflictbench import InfrastructureError, PolicyClient, ServerUnavailable, UserError
from conflictbench.hosting import transport as transports
from conflictbench.hosting import trust

serving = pytest.importorskip("conflictbench_serving")
from conflictbench_serving import guard as guards  # noqa: E402 (after the check that the serving half is here)
from conflictbench_serving.batching import Batcher  # noqa: E402
from conflictbench_serving.guard import Guard  # noqa: E402

TIMEOUT_S = 10


@contextmanager
def running(server):
    """One of our servers (``run(host, port, stop, on_ready)``) on a free port, its event loop in a thread."""
    bound, ready = {}, threading.Event()

    async def main() -> None:
        bound["loop"], bound["stop"] = asyncio.get_running_loop(), asyncio.Event()
        await server.run("127.0.0.1", 0, bound["stop"], lambda host, port: (bound.update(port=port), ready.set()))

    thread = threading.Thread(target=asyncio.run, args=(main(),), daemon=True)
    thread.start()
    assert ready.wait(TIMEOUT_S), "the server did not bind"
    try:
        yield bound["port"]
    finally:
        bound["loop"].call_soon_threadsafe(bound["stop"].set)
        thread.join(TIMEOUT_S)


def test_the_clients_bound_and_header_are_the_servers():
    assert transports.MESSAGE_LIMIT_VARIABLE == guards.MESSAGE_LIMIT_VARIABLE
    assert transports.DEFAULT_MAX_MESSAGE_BYTES == guards.DEFAULT_MAX_MESSAGE_BYTES
    assert transports.authorization("t") == guards.authorization("t") and transports.authorization(None) == {}
    assert trust.TOKEN_VARIABLE == guards.TOKEN_VARIABLE  # restated: conflictbench's core install needs no serving


# The message bound's variable, as a run and its servers read it: each value accepted by both, or refused by both.
LIMITS = ["1000", " 1000 ", "12582912", "0", "-5", "+5", "1_000", "1e6", "\u00b2", "\u0663", "lots", "5.0"]


@pytest.mark.parametrize("text", LIMITS)
def test_a_run_and_its_servers_read_the_message_bound_alike(monkeypatch, text):
    monkeypatch.setenv(guards.MESSAGE_LIMIT_VARIABLE, text)
    try:
        server = guards.message_limit_from_environment()
    except ValueError:
        server = "refused"
    try:
        run = transports.message_limit()
    except UserError:
        run = "refused"
    assert run == server
    assert server == "refused" or text.strip() in ("1000", "12582912")  # plain ASCII digits, nothing else


# ---- openpi's websocket ------------------------------------------------------------------------------------------


def _websocket_server(guard: Guard | None = None):
    from conflictbench_serving.msgpack_numpy import packb, unpackb
    from conflictbench_serving.websocket import WebsocketPolicyServer

    async def answer(frame, session):  # a reply of the size asked for
        size, _ = await server.batcher.submit(unpackb(frame)["size"])
        return packb({"blob": b"x" * size})

    server = WebsocketPolicyServer(answer, packb({"hosted": "blobs"}), Batcher(lambda r: r, 1, False), guard=guard)
    return server


def test_openpi_sends_the_token_and_a_refused_one_stops_the_run_in_one_line():
    from conflictbench.hosting.openpi import OpenpiTransport

    with running(_websocket_server(Guard(token="s3cret"))) as port:
        url = f"ws://127.0.0.1:{port}"
        good = OpenpiTransport(url, token="s3cret")
        good.connect(TIMEOUT_S)
        assert good.metadata == {"hosted": "blobs"} and len(good.exchange({"size": 3}, TIMEOUT_S)["blob"]) == 3
        good.close()
        for token in (None, "wrong"):
            with pytest.raises(PermissionError, match="refused this run's token: HTTP 401 Unauthorized") as refused:
                OpenpiTransport(url, token=token).connect(TIMEOUT_S)
            assert "\n" not in str(refused.value) and "s3cret" not in str(refused.value)
        client = PolicyClient(url, lambda url: OpenpiTransport(url, token="wrong"), connect_retries=5)
        started = time.monotonic()
        with pytest.raises(ServerUnavailable, match="refused this run's token: HTTP 401 .*CONFLICTBENCH_SERVER_TOKEN"):
            client.open()  # at once: asking again with the same token cannot help
        assert time.monotonic() - started < 2


def test_openpi_bounds_what_it_reads_and_sends_and_says_so():
    from conflictbench.hosting.openpi import OpenpiTransport

    with running(_websocket_server(Guard(max_message_bytes=50_000))) as port:
        url = f"ws://127.0.0.1:{port}"
        small = OpenpiTransport(url, max_message_bytes=10_000)
        small.connect(TIMEOUT_S)
        with pytest.raises(InfrastructureError, match="a reply of more than 10000 bytes .*CONFLICTBENCH_MAX_MESSAGE"):
            small.exchange({"size": 20_000}, TIMEOUT_S)
        small.connect(TIMEOUT_S)
        with pytest.raises(InfrastructureError, match="a request of \\d+ bytes is over the limit of 10000 bytes"):
            small.exchange({"size": 1, "pad": b"x" * 20_000}, TIMEOUT_S)
        large = OpenpiTransport(url)  # the run allows more than this server: the server's refusal says so
        large.connect(TIMEOUT_S)
        with pytest.raises(InfrastructureError, match="refused a request of \\d+ bytes as too big"):
            large.exchange({"size": 1, "pad": b"x" * 60_000}, TIMEOUT_S)
        small.close(), large.close()


def test_openpi_reads_the_last_line_of_the_traceback_openpis_servers_send():
    """openpi's own server answers a failure with its whole traceback as a text frame, then closes (1011)."""
    from websockets.asyncio.server import serve

    from conflictbench.hosting.openpi import OpenpiTransport
    from conflictbench_serving.msgpack_numpy import packb

    traceback = 'Traceback (most recent call last):\n  File "x.py", line 1, in infer\nValueError: no such camera\n'

    class OpenpiLike:
        async def run(self, host, port, stop, on_ready):
            async def handle(connection):
                await connection.send(packb({}))
                await connection.recv()
                await connection.send(traceback)
                await connection.close(1011, "Internal server error")

            async with serve(handle, host, port) as server:
                on_ready(host, next(iter(server.sockets)).getsockname()[1])
                await stop.wait()

    with running(OpenpiLike()) as port:
        client = OpenpiTransport(f"ws://127.0.0.1:{port}")
        client.connect(TIMEOUT_S)
        with pytest.raises(InfrastructureError, match="answered an error: ValueError: no such camera$"):
            client.exchange({"a": 1}, TIMEOUT_S)


# ---- deploy.py's REST --------------------------------------------------------------------------------------------


@contextmanager
def rest_server(guard: Guard):
    uvicorn = pytest.importorskip("uvicorn")
    from conflictbench_serving import rest

    class Echo:
        metadata = {"hosted": "echo"}

        def infer_batch(self, rows):
            return rows

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    app = rest.build_app(Echo(), 1, lambda body: (body.decode(), False), "echo", guard)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False, **rest.limits(guard)))
    thread = threading.Thread(target=asyncio.run, args=(server.serve(sockets=[sock]),), daemon=True)
    thread.start()
    while not server.started:
        threading.Event().wait(0.01)
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(TIMEOUT_S)


def test_json_numpy_sends_the_token_on_every_request_and_a_refused_one_stops_the_run():
    pytest.importorskip("json_numpy")
    from conflictbench.hosting.rest import JsonNumpyTransport

    with rest_server(Guard(token="s3cret")) as url:
        good = JsonNumpyTransport(url, token="s3cret")
        good.connect(TIMEOUT_S)  # GET /metadata, with the token
        assert good.metadata["hosted"] == "echo"
        assert good.exchange("hello", TIMEOUT_S) == '"hello"'  # POST /act, with the token
        good.close()
        for token in (None, "wrong"):
            with pytest.raises(PermissionError, match="refused this run's token: HTTP 401") as refused:
                JsonNumpyTransport(url, token=token).connect(TIMEOUT_S)
            assert "\n" not in str(refused.value) and "s3cret" not in str(refused.value)


@contextmanager
def big_reply_server(size: int, chunked: bool, reply: bytes | None = None):
    """A plain HTTP server whose every reply is a JSON string of ``size`` bytes (declared, or chunked), or
    ``reply``."""

    class Handler(http.server.BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def do_POST(self):
            self.rfile.read(int(self.headers.get("Content-Length", 0)))
            body = reply if reply is not None else b'"' + b"x" * (size - 2) + b'"'
            self.send_response(200)
            if chunked:
                self.send_header("Transfer-Encoding", "chunked")
                self.end_headers()
                for start in range(0, len(body), 4096):
                    piece = body[start : start + 4096]
                    self.wfile.write(f"{len(piece):x}\r\n".encode() + piece + b"\r\n")
                self.wfile.write(b"0\r\n\r\n")
            else:
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/act"
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize("chunked", [False, True], ids=["declared", "chunked"])
def test_http_replies_are_read_no_further_than_the_bound(chunked):
    with big_reply_server(50_000, chunked) as url:
        client = transports.HttpJsonTransport(url, max_message_bytes=10_000)
        client.connect(TIMEOUT_S)
        size = "more than 10000" if chunked else "50000"
        with pytest.raises(InfrastructureError, match=f"a reply of {size} bytes is over the limit of 10000 bytes"):
            client.exchange({"a": 1}, TIMEOUT_S)
        roomy = transports.HttpJsonTransport(url, max_message_bytes=60_000)
        roomy.connect(TIMEOUT_S)
        assert len(roomy.exchange({"a": 1}, TIMEOUT_S)) == 50_000 - 2
        roomy.close()


def test_json_numpy_says_why_it_refused_an_array_in_a_reply():
    from conflictbench.hosting.rest import JsonNumpyTransport

    objects = b'[{"__numpy__": "QUFBQUFBQUFBQUFBQUFBQQ==", "dtype": "|O", "shape": [2]}]'
    with big_reply_server(0, False, reply=objects) as url:
        client = JsonNumpyTransport(url)
        client.connect(TIMEOUT_S)
        with pytest.raises(InfrastructureError) as refused:
            client.exchange({"a": 1}, TIMEOUT_S)
        client.close()
    message = str(refused.value)
    assert "arrays of dtype '|O' are refused" in message and "not JSON" not in message and "\n" not in message


def test_a_bad_message_bound_in_the_environment_is_one_line(monkeypatch):
    from conflictbench import UserError

    monkeypatch.setenv("CONFLICTBENCH_MAX_MESSAGE_BYTES", "lots")
    with pytest.raises(UserError, match="CONFLICTBENCH_MAX_MESSAGE_BYTES .* must be a positive number of bytes"):
        transports.HttpJsonTransport("http://127.0.0.1:1/act")
    monkeypatch.setenv("CONFLICTBENCH_MAX_MESSAGE_BYTES", "2000")
    assert transports.HttpJsonTransport("http://127.0.0.1:1/act").max_message_bytes == 2000


# ---- GR00T's ZeroMQ ----------------------------------------------------------------------------------------------


def test_zeromq_stops_at_once_on_a_refused_token_and_bounds_what_it_sends():
    pytest.importorskip("zmq")
    from conflictbench.hosting.zeromq import ZmqTransport
    from conflictbench_serving.zeromq import ZmqPolicyServer

    class Echo(ZmqPolicyServer):
        async def get_action(self, data):
            return (await self.batcher.submit(data))[0]

    with running(Echo(Batcher(lambda r: r, 1, False), {}, guard=Guard(token="s3cret"))) as port:
        url = f"tcp://127.0.0.1:{port}"
        with pytest.raises(PermissionError, match="refused this run's token: .*Unauthorized: Invalid API token"):
            ZmqTransport(url, api_token="wrong").connect(TIMEOUT_S)
        small = ZmqTransport(url, api_token="s3cret", max_message_bytes=1000)
        small.connect(TIMEOUT_S)
        request = {"endpoint": "get_action", "data": {"x": 1}, "api_token": "s3cret"}
        assert small.exchange(request, TIMEOUT_S) == {"x": 1}
        with pytest.raises(InfrastructureError, match="a request of \\d+ bytes is over the limit of 1000 bytes"):
            small.exchange({**request, "data": {"x": "y" * 2000}}, TIMEOUT_S)
        small.close()
