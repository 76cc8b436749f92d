"""Our UniVLA server (model environment): the protocol of ``.protocol`` on conflictbench-serving's REST server.

Upstream has no server. This one is ``deploy.py``'s shape (``conflictbench_serving.rest``: FastAPI, json-numpy
``POST /act``, ``/healthz``, ``/metadata``, ``{"error": ...}`` answers, one model thread) with UniVLA's request:
the image, the text, the client's latent history, the statistics key and the request's seed.

``SERVED`` is what ``conflictbench-serve univla`` hosts (found through the server half's ``conflictbench_serving``
entry point) and what the client's ``served`` names. This module imports neither conflictbench nor torch (the
backend's model is loaded by name, after the checks), so the client imports ``SERVED`` from it cheaply.
"""

import numpy as np

from conflictbench_serving import rest
from conflictbench_serving.arrays import json_numpy_loads
from conflictbench_serving.checkpoints import NOISE_SEED
from conflictbench_serving.command import ServedModel
from conflictbench_serving.requests import describe, is_noise_seed

from .backend import Row
from .checkpoints import check_checkpoint, check_code


def check(folder, policy: str, naming: str) -> None:
    check_code()  # the model's code, from the checkout UNIVLA_CODE names
    check_checkpoint(folder)


#: A UniVLA checkpoint, UniVLA's code read from ``UNIVLA_CODE``.
SERVED = ServedModel.of(
    __package__,
    policies=("univla",),
    protocol="our REST protocol (json-numpy)",
    check=check,
    url_scheme="http",
    checkpoint_help="a UniVLA checkpoint folder: the VLA in Hugging Face format and action_decoder.pt",
)


def request_row(body: bytes) -> tuple[Row, bool]:
    """The row a body asks for (never double-encoded: no upstream client of this protocol exists)."""
    try:
        payload = json_numpy_loads(body)
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
