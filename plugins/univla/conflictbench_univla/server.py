"""Our UniVLA server (model environment): the protocol of ``.protocol`` on conflictbench-serving's REST server.

Upstream has no server. This one is ``deploy.py``'s shape (``conflictbench_serving.rest``: FastAPI, json-numpy
``POST /act``, ``/healthz``, ``/metadata``, ``{"error": ...}`` answers, one model thread) with UniVLA's request:
the image, the text, the client's latent history, the statistics key and the request's seed.

This module imports neither conflictbench nor torch.
"""

import json_numpy
import numpy as np

from conflictbench_serving import rest
from conflictbench_serving.checkpoints import NOISE_SEED
from conflictbench_serving.requests import describe, is_noise_seed

from .backend import Row


def request_row(body: bytes) -> tuple[Row, bool]:
    """The row a body asks for (never double-encoded: no upstream client of this protocol exists)."""
    try:
        payload = json_numpy.loads(body)
    except (ValueError, TypeError) as error:
        raise rest.InvalidRequest(f"not a json-numpy body: {error}") from None
    if not isinstance(payload, dict):
        raise rest.InvalidRequest("the body must be a JSON object")
    image = payload.get("image")
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise rest.InvalidRequest("'image' must be a json-numpy uint8 array H x W x 3")
    texts = [payload.get(name) for name in ("instruction", "history", "unnorm_key")]
    if not all(isinstance(text, str) for text in texts):
        raise rest.InvalidRequest("'instruction', 'history' and 'unnorm_key' must be texts")
    seed = payload.get(NOISE_SEED)
    if seed is not None and not is_noise_seed(seed):
        raise rest.InvalidRequest(f"{NOISE_SEED} must be an int in [0, 2**63), got {describe(seed)}")
    return Row(image, *texts, seed), False


def serve(backend, host: str, port: int, max_batch: int, on_ready) -> None:
    """Serve ``backend`` until SIGINT / SIGTERM."""
    rest.serve(backend, host, port, max_batch, on_ready, parse=request_row, name="univla")
