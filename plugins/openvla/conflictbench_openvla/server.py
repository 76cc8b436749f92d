"""``deploy.py``'s REST protocol hosting an OpenVLA checkpoint (model environment): OpenVLA's request on
conflictbench-serving's REST server (:mod:`conflictbench_serving.rest`).

What upstream's server does, kept: ``POST /act`` with a json-numpy body ``{image, instruction, unnorm_key?}`` or
the double-encoded ``{"encoded": text}`` (answered the same way: a JSON string holding the json-numpy text); the
reply, the un-normalized action as a json-numpy float64 array of 7. ``GET /metadata`` says the policy type, the
checkpoint's fingerprint, ``max_batch`` and its statistics keys.

This module imports neither conflictbench nor torch.
"""

import json_numpy
import numpy as np

from conflictbench_serving import rest
from conflictbench_serving.rest import InvalidRequest

from .backend import Row


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


def serve(backend, host: str, port: int, max_batch: int, on_ready) -> None:
    """Serve ``backend`` until SIGINT / SIGTERM."""
    rest.serve(backend, host, port, max_batch, on_ready, parse=request_row, name="openvla")
