"""``deploy.py``'s REST protocol, server side, with batching: the server the OpenVLA family's plugins share.

What upstream's server (``vla-scripts/deploy.py``) does, kept: FastAPI and uvicorn; ``POST /act`` with a json-numpy
body, answered with json-numpy (a body that came double-encoded, ``{"encoded": text}``, answered the same way: a
JSON string holding the json-numpy text). What a body holds is the model's: the plugin gives ``parse`` (a body to
the row its backend answers, raising :class:`InvalidRequest`).

Ours adds: ``GET /healthz``; ``GET /metadata`` (the backend's metadata, ``max_batch`` and ``fixed_shape``), which a
client reads to name what it plays; the requests of every connection queued into one model thread (the
:class:`~.batching.Batcher`, fixed shape); and a failure's message: ``{"error": message}`` with HTTP 500 where
``deploy.py`` answers ``"error"`` with HTTP 200 (both are errors to every client; ours says why).

What a peer may do is the :class:`~.guard.Guard`'s (the app's own, else the process-wide one): with a token, every
request but ``GET /healthz`` must carry ``Authorization: Api-Key <token>`` (HTTP 401 otherwise); a body over
``max_message_bytes`` is refused with HTTP 413 before it is read whole (its ``Content-Length``, else as it streams);
uvicorn answers HTTP 503 beyond ``max_connections`` connections (``limit_concurrency``, which counts connections
before any token is seen): so a connection that has not sent a whole request's headers within
:data:`FIRST_REQUEST_S` is closed (uvicorn itself would hold it open for ever), and one idle after a reply is
closed after uvicorn's keep-alive timeout; the batcher queues at most ``max_queued`` requests (HTTP 503, busy,
beyond). Every error is ``{"error": one line}``; a failed model call's traceback stays in the server's log.

Needs ``fastapi``, ``uvicorn`` and ``json-numpy`` (the ``rest`` extra). Imports neither conflictbench nor torch.
"""

import asyncio
import contextlib
import json
import socket
from collections.abc import Callable
from typing import Any, Protocol

import json_numpy

from .batching import Batcher, ServerBusy, ServerStopping
from .guard import AUTHORIZATION, UNAUTHORIZED, Guard, current, error_line, one_line

HEALTH_ROUTE = "/healthz"  # answers without the token: it says nothing but "up"
#: Seconds a new connection has to send a whole request's headers (our clients send theirs at once); then it is
#: closed, so connections that never ask cannot hold every one of the ``max_connections``.
FIRST_REQUEST_S = 5.0


class Backend(Protocol):
    metadata: dict

    def infer_batch(self, rows: list[Any]) -> list[Any]:
        """Each row's answer (sent as json-numpy)."""
        ...


class InvalidRequest(ValueError):
    """A body that is not the protocol's request (answered HTTP 400 with the message)."""


#: A body read into the row the backend answers, and whether it came double-encoded.
ParseRequest = Callable[[bytes], tuple[Any, bool]]


def build_app(backend: Backend, max_batch: int, parse: ParseRequest, name: str, guard: Guard | None = None):
    """The app (FastAPI, inside the guard's checks); its lifespan runs the batcher. ``parse`` reads a body (raise
    :class:`InvalidRequest`); the backend's answers go out as json-numpy. ``guard`` None: the process-wide one."""
    from fastapi import FastAPI, Request
    from fastapi.responses import JSONResponse, Response

    guard = current() if guard is None else guard
    limit = guard.max_message_bytes
    batcher = Batcher(backend.infer_batch, max_batch, fixed_shape=True, name=name, max_queued=guard.max_queued)
    metadata = {**backend.metadata, "max_batch": max_batch, "fixed_shape": True}

    @contextlib.asynccontextmanager
    async def lifespan(app):
        task = asyncio.create_task(batcher.run())
        try:
            yield
        finally:
            task.cancel()
            batcher.shutdown()

    app = FastAPI(lifespan=lifespan)

    def error(message: str, status: int = 500) -> JSONResponse:
        return JSONResponse({"error": message}, status_code=status)

    @app.post("/act")
    async def act(request: Request) -> Any:
        body = bytearray()
        async for chunk in request.stream():  # a body sent without Content-Length: counted as it comes
            body += chunk
            if len(body) > limit:
                return error(_too_large(limit), 413)
        try:
            row, encoded = parse(bytes(body))
        except InvalidRequest as problem:
            return error(one_line(f"invalid request: {problem}"), 400)
        try:
            answer, _timing = await batcher.submit(row)
        except ServerStopping:
            return error("the server is stopping", 503)
        except ServerBusy as problem:
            return error(f"ServerBusy: {problem}", 503)
        except Exception as problem:  # the model call failed: this request's answer, the server goes on
            return error(error_line(problem))  # the batcher logged its traceback
        text = json_numpy.dumps(answer)
        return Response(json.dumps(text) if encoded else text, media_type="application/json")

    @app.get(HEALTH_ROUTE)
    async def healthz() -> dict:
        return {"status": "ok"}

    @app.get("/metadata")
    async def describe() -> dict:
        return metadata

    return _Guarded(app, guard)


class _Guarded:
    """The ASGI app inside the guard's checks, made before FastAPI reads anything: the token on every route but
    ``/healthz``, and a declared ``Content-Length`` over the limit (a streamed body is counted in ``/act``)."""

    def __init__(self, app, guard: Guard) -> None:
        self.app, self.guard = app, guard

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] == "http":
            headers = dict(scope["headers"])
            authorization = headers.get(AUTHORIZATION.lower().encode(), b"").decode("latin-1")
            if scope["path"] != HEALTH_ROUTE and not self.guard.admits_header(authorization):
                return await _send_error(send, 401, UNAUTHORIZED)
            length = headers.get(b"content-length", b"0").decode("latin-1").strip()
            if not length.isdigit() or int(length) > self.guard.max_message_bytes:
                return await _send_error(send, 413, _too_large(self.guard.max_message_bytes))
        await self.app(scope, receive, send)

    def __getattr__(self, name: str):  # the FastAPI app's routes, state and so on, for tests and tools
        return getattr(self.app, name)


async def _send_error(send, status: int, message: str) -> None:
    body = json.dumps({"error": message}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


def _too_large(limit: int) -> str:
    return f"the body is over this server's limit of {limit} bytes (conflictbench-serve --max-message-mib)"


def serve(
    backend: Backend,
    host: str,
    port: int,
    max_batch: int,
    on_ready: Callable[[str, int], None],
    parse: ParseRequest,
    name: str,
    guard: Guard | None = None,
) -> None:
    """Serve until SIGINT / SIGTERM (uvicorn's own handling: a clean exit). A port that cannot be bound raises
    OSError before anything is served."""
    import uvicorn

    guard = current() if guard is None else guard
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    app = build_app(backend, max_batch, parse, name, guard)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False, **limits(guard)))

    async def run() -> None:
        serving = asyncio.create_task(server.serve(sockets=[sock]))
        while not server.started and not serving.done():
            await asyncio.sleep(0.02)
        if server.started:
            on_ready(host, sock.getsockname()[1])
        await serving

    asyncio.run(run())


def limits(guard: Guard, first_request_s: float = FIRST_REQUEST_S) -> dict:
    """uvicorn's settings for ``guard``: HTTP 503 beyond ``max_connections`` (uvicorn counts the connection asking,
    so one more; an idle keep-alive connection is closed after uvicorn's 5 s), and its HTTP protocol closing a
    connection that sends no whole request within ``first_request_s``."""
    from uvicorn.protocols.http.auto import AutoHTTPProtocol

    return {
        "limit_concurrency": guard.max_connections + 1,
        "http": _with_request_deadline(AutoHTTPProtocol, first_request_s),
    }


def _with_request_deadline(protocol: type, seconds: float) -> type:
    """uvicorn's HTTP ``protocol``, closing a connection whose first request's headers are not all in within
    ``seconds`` (uvicorn starts no timer before a first request: an idle stranger would hold a connection slot for
    ever, and ``limit_concurrency`` counts it before any token is checked)."""

    class FirstRequestDeadline(protocol):
        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self._deadline = asyncio.get_running_loop().call_later(seconds, self._no_request)

        def _no_request(self) -> None:
            if self.cycle is None and not self.transport.is_closing():  # uvicorn makes a cycle per whole header
                self.transport.close()

        def connection_lost(self, exc) -> None:
            self._deadline.cancel()
            super().connection_lost(exc)

    return FirstRequestDeadline
