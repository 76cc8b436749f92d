"""``deploy.py``'s REST protocol hosting an OpenVLA checkpoint (model environment): OpenVLA's request on
conflictbench-serving's REST server (:mod:`conflictbench_serving.rest`).

What upstream's server does, kept: ``POST /act`` with a json-numpy body ``{image, instruction, unnorm_key?}`` or
the double-encoded ``{"encoded": text}`` (answered the same way: a JSON string holding the json-numpy text); the
reply, the un-normalized action as a json-numpy float64 array of 7. ``GET /metadata`` says the policy type, the
checkpoint's fingerprint, ``max_batch`` and its statistics keys.

``SERVED`` is what ``conflictbench-serve openvla`` hosts (found through the server half's ``conflictbench_serving``
entry point) and what the client's ``served`` names. This module imports neither conflictbench nor torch (the
backend's model is loaded by name, after the checks), so the client imports ``SERVED`` from it cheaply.
"""

import numpy as np

from conflictbench_serving import rest
from conflictbench_serving.arrays import json_numpy_loads
from conflictbench_serving.command import ServedModel
from conflictbench_serving.rest import InvalidRequest

from .backend import Row
from .checkpoints import check_checkpoint

#: An OpenVLA checkpoint in Hugging Face format.
SERVED = ServedModel.of(
    __package__,
    policies=("openvla", "openvla-oft"),  # our server hosts OpenVLA; it refuses OFT in one line
    protocol="deploy.py's REST protocol (json-numpy)",
    check=lambda folder, policy, naming: check_checkpoint(folder, policy),
    url_scheme="http",
    checkpoint_help="an OpenVLA checkpoint folder in Hugging Face format (with its own model code)",
)


def request_row(body: bytes) -> tuple[Row, bool]:
    """The row a body asks for, and whether it came double-encoded (its answer is then encoded too)."""
    try:
        payload = json_numpy_loads(body)
        encoded = isinstance(payload, dict) and "encoded" in payload
        if encoded:
            if len(payload) != 1:
                raise InvalidRequest("an encoded request holds nothing but 'encoded'")
            payload = json_numpy_loads(payload["encoded"])
    except (ValueError, TypeError) as error:
        raise InvalidRequest(f"not a json-numpy body: {error}") from None
    except KeyError as error:  # a "__numpy__" object without its dtype or shape: a 400, not a 500 with a traceback
        raise InvalidRequest(f"not a json-numpy body: an array without its {error}") from None
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
