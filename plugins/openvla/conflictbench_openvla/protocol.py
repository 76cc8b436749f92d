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

Requests and replies go through the ``json-numpy`` package itself (the transport, conflictbench's own:
:class:`conflictbench.hosting.rest.JsonNumpyTransport`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench.hosting.rest import ERROR_REPLY, METADATA_ROUTE, ROUTE, JsonNumpyTransport

__all__ = [
    "ERROR_REPLY",
    "METADATA_ROUTE",
    "ROUTE",
    "JsonNumpyTransport",
    "oft_request",
    "openvla_request",
    "read_action",
    "read_chunk",
]


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
