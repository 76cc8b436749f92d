"""The OpenVLA family's inference protocol: ``vla-scripts/deploy.py``'s REST ``POST /act`` with json-numpy bodies.

The facts, from openvla/openvla's and moojink/openvla-oft's ``vla-scripts/deploy.py``:

- FastAPI, one route ``POST /act`` (port 8000 for OpenVLA, 8777 for OFT); ``json_numpy.patch()`` makes every
  JSON body json-numpy: an array is ``{"__numpy__": base64 of its C-order bytes, "dtype": "<f8", "shape": [7]}``;
- OpenVLA's request: ``{"image": uint8 H x W x 3, "instruction": text, "unnorm_key": key}``; the reply, the
  un-normalized action, a float64 array of 7;
- OFT's request: ``{"full_image", "wrist_image": uint8 images, "state": the raw 8-D state, "instruction"}``
  (its ``unnorm_key`` was fixed when the server started); the reply, a list of 8 float64 arrays of 7;
- any failure in the handler answers the JSON string ``"error"`` with HTTP 200 (its traceback stays in the
  server's log); a body FastAPI cannot read, HTTP 422.

Requests and replies go through the ``json-numpy`` package itself (:class:`JsonNumpyTransport`).
"""

from __future__ import annotations

import http.client
import json
import urllib.parse
from typing import Any

import json_numpy
import numpy as np

from conflictbench import InfrastructureError
from conflictbench.core.transport import HttpJsonTransport

ROUTE = "/act"
METADATA_ROUTE = "/metadata"
ERROR_REPLY = "error"


class JsonNumpyTransport(HttpJsonTransport):
    """HTTP POST of json-numpy bodies to ``/act`` (a URL without a path gets it); ``"error"`` replies raise.

    On connecting it asks ``GET /metadata`` (beside ``/act``): our server says what it hosts there; upstream's
    ``deploy.py`` has no such route (404), and ``metadata`` stays empty.
    """

    def __init__(self, url: str):
        parts = urllib.parse.urlsplit(url)
        if parts.path in ("", "/"):
            parts = parts._replace(path=ROUTE)
        super().__init__(urllib.parse.urlunsplit(parts))
        self._metadata_path = parts.path.rsplit("/", 1)[0] + METADATA_ROUTE
        self.metadata: dict[str, Any] = {}

    def connect(self, timeout: float) -> None:
        super().connect(timeout)
        self.metadata = {}
        try:
            self._conn.request("GET", self._metadata_path)
            response = self._conn.getresponse()
            data = response.read()
        except http.client.HTTPException as exc:
            raise ConnectionError(f"{type(exc).__name__}: {exc}") from exc
        if response.status == 200:
            try:
                metadata = json.loads(data)
            except ValueError:
                metadata = None
            self.metadata = metadata if isinstance(metadata, dict) else {}

    def dumps(self, request: Any) -> str:
        return json_numpy.dumps(request)

    def loads(self, text: bytes) -> Any:
        try:
            reply = json_numpy.loads(text)
        except (KeyError, TypeError) as exc:  # a "__numpy__" object without dtype or shape, an unknown dtype
            raise ValueError(f"a json-numpy array that cannot be read ({type(exc).__name__}: {exc})") from None
        if isinstance(reply, str) and reply == ERROR_REPLY:
            raise InfrastructureError(
                f'{self.url} answered "error": the server caught an exception on this request (its log has the '
                "traceback; deploy.py answers every failure so, e.g. an unnorm_key the checkpoint lacks)"
            )
        return reply


def openvla_request(image: np.ndarray, instruction: str, unnorm_key: str) -> dict[str, Any]:
    """OpenVLA's ``/act`` body: the processed image, the task text as it is (the server lower-cases it)."""
    return {"image": np.ascontiguousarray(image, dtype=np.uint8), "instruction": instruction, "unnorm_key": unnorm_key}


def oft_request(full_image: np.ndarray, wrist_image: np.ndarray, state: np.ndarray, instruction: str) -> dict:
    """OFT's ``/act`` body: both images resized (the server crops them), the raw 8-D state (it normalizes it)."""
    return {
        "full_image": np.ascontiguousarray(full_image, dtype=np.uint8),
        "wrist_image": np.ascontiguousarray(wrist_image, dtype=np.uint8),
        "state": np.asarray(state, dtype=np.float64),
        "instruction": instruction,
    }


def read_action(reply: Any) -> np.ndarray:
    """OpenVLA's reply: one action of 7 (float64, writable)."""
    try:
        action = np.array(reply, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"expected an action of 7 values, got {type(reply).__name__}") from None
    if action.shape != (7,):
        raise ValueError(f"expected an action of 7 values, got shape {action.shape}")
    return action


def read_chunk(reply: Any) -> np.ndarray:
    """OFT's reply: a list of actions of 7, as one (k, 7) float64 array."""
    if not isinstance(reply, list) or not reply:
        raise ValueError(f"expected a list of actions, got {type(reply).__name__}")
    try:
        chunk = np.array([np.asarray(action, dtype=np.float64) for action in reply])
    except (TypeError, ValueError):
        raise ValueError("expected a list of actions of 7 values") from None
    if chunk.ndim != 2 or chunk.shape[1] != 7:
        raise ValueError(f"expected actions of 7 values, got shape {chunk.shape}")
    return chunk
