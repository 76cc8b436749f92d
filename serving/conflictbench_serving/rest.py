"""``deploy.py``'s REST protocol, server side, with batching: the server the OpenVLA family's plugins share.

What upstream's server (``vla-scripts/deploy.py``) does, kept: FastAPI and uvicorn; ``POST /act`` with a json-numpy
body, answered with json-numpy (a body that came double-encoded, ``{"encoded": text}``, answered the same way: a
JSON string holding the json-numpy text). What a body holds is the model's: the plugin gives ``parse`` (a body to
the row its backend answers, raising :class:`InvalidRequest`).

Ours adds: ``GET /healthz``; ``GET /metadata`` (the backend's metadata, ``max_batch`` and ``fixed_shape``), which a
client reads to name what it plays; the requests of every connection queued into one model thread (the
:class:`~.batching.Batcher`, fixed shape); and a failure's message: ``{"error": message}`` with HTTP 500 where
``deploy.py`` answers ``"error"`` with HTTP 200 (both are errors to every client; ours says why).

Needs ``fastapi``, ``uvicorn`` and ``json-numpy`` (the ``rest`` extra). Imports neither conflictbench nor torch.
"""

import asyncio
import contextlib
import json
import socket
from collections.abc import Callable
from typing import Any, Protocol

import json_numpy

from .batching import Batcher, ServerStopping


class Backend(Protocol):
    metadata: dict

    def infer_batch(self, rows: list[Any]) -> list[Any]:
        """Each row's answer (sent as json-numpy)."""
        ...


class InvalidRequest(ValueError):
    """A body that is not the protocol's request (answered HTTP 400 with the message)."""


#: A body read into the row the backend answers, and whether it came double-encoded.
ParseRequest = Callable[[bytes], tuple[Any, bool]]


def build_app(backend: Backend, max_batch: int, parse: ParseRequest, name: str):
    """The FastAPI app; its lifespan runs the batcher. ``parse`` reads a body (raise :class:`InvalidRequest`);
    the backend's answers go out as json-numpy."""
    from fastapi import FastAPI, Request
    from fastapi.responses import JSONResponse, Response

    batcher = Batcher(backend.infer_batch, max_batch, fixed_shape=True, name=name)
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
        try:
            row, encoded = parse(await request.body())
        except InvalidRequest as problem:
            return error(f"invalid request: {problem}", 400)
        try:
            answer, _timing = await batcher.submit(row)
        except ServerStopping:
            return error("the server is stopping", 503)
        except Exception as problem:  # the model call failed: this request's answer, the server goes on
            return error(f"{type(problem).__name__}: {problem}")
        text = json_numpy.dumps(answer)
        return Response(json.dumps(text) if encoded else text, media_type="application/json")

    @app.get("/healthz")
    async def healthz() -> dict:
        return {"status": "ok"}

    @app.get("/metadata")
    async def describe() -> dict:
        return metadata

    return app


def serve(
    backend: Backend,
    host: str,
    port: int,
    max_batch: int,
    on_ready: Callable[[str, int], None],
    parse: ParseRequest,
    name: str,
) -> None:
    """Serve until SIGINT / SIGTERM (uvicorn's own handling: a clean exit). A port that cannot be bound raises
    OSError before anything is served."""
    import uvicorn

    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    app = build_app(backend, max_batch, parse, name)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False))

    async def run() -> None:
        serving = asyncio.create_task(server.serve(sockets=[sock]))
        while not server.started and not serving.done():
            await asyncio.sleep(0.02)
        if server.started:
            on_ready(host, sock.getsockname()[1])
        await serving

    asyncio.run(run())
