"""``deploy.py``'s REST protocol with batching, hosting an OpenVLA checkpoint (model environment).

What upstream's server does, kept: FastAPI and uvicorn; ``POST /act`` with a json-numpy body ``{image,
instruction, unnorm_key?}`` or the double-encoded ``{"encoded": text}`` (answered the same way: a JSON string
holding the json-numpy text); the reply, the un-normalized action as a json-numpy float64 array of 7.

Ours adds: ``GET /healthz``; ``GET /metadata`` (the policy type, the checkpoint's fingerprint, ``max_batch``, its
statistics keys), which a client reads to name what it plays; the requests of every connection queued into one
model thread (conflictbench-serving's batcher); and a failure's message: ``{"error": message}`` with HTTP 500
where ``deploy.py`` answers ``"error"`` with HTTP 200 (both are errors to every client; ours says why).

This module imports neither conflictbench nor torch.
"""

import asyncio
import contextlib
import json
import socket
from collections.abc import Callable
from typing import Any, Protocol

import json_numpy
import numpy as np

from conflictbench_serving.batching import Batcher, ServerStopping

from .backend import Row


class Backend(Protocol):
    metadata: dict

    def infer_batch(self, rows: list[Row]) -> list[np.ndarray]: ...


class InvalidRequest(ValueError):
    """A body that is not ``deploy.py``'s request."""


def request_row(body: bytes) -> tuple[Row, bool]:
    """The row a body asks for, and whether it came double-encoded (its answer is then encoded too)."""
    try:
        payload = json_numpy.loads(body)
        encoded = isinstance(payload, dict) and "encoded" in payload
        if encoded:
            if len(payload) != 1:
                raise InvalidRequest("an encoded request holds nothing but 'encoded'")
            payload = json_numpy.loads(payload["encoded"])
    except (ValueError, TypeError) as error:
        raise InvalidRequest(f"not a json-numpy body: {error}") from None
    if not isinstance(payload, dict):
        raise InvalidRequest("the body must be a JSON object {'image': np.ndarray, 'instruction': str}")
    image, instruction, key = payload.get("image"), payload.get("instruction"), payload.get("unnorm_key")
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise InvalidRequest("'image' must be a json-numpy uint8 array H x W x 3")
    if not isinstance(instruction, str) or not (key is None or isinstance(key, str)):
        raise InvalidRequest("'instruction' must be a text, 'unnorm_key' a text or missing")
    return Row(image, instruction, key), encoded


#: A body read into the row the backend answers, and whether it came double-encoded.
ParseRequest = Callable[[bytes], tuple[Any, bool]]


def build_app(backend: Backend, max_batch: int, parse: ParseRequest = request_row, name: str = "openvla"):
    """The FastAPI app; its lifespan runs the batcher. ``parse`` reads a body (raise :class:`InvalidRequest`);
    the backend's answers go out as json-numpy (another model's protocol on the same server: UniVLA's)."""
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
    parse: ParseRequest = request_row,
    name: str = "openvla",
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
