"""openpi's wire format: msgpack with numpy arrays, over a websocket (both sides use this module).

The facts, from openpi-client's ``msgpack_numpy`` and ``websocket_policy_server`` (PyPI, 0.1.x):

- an array is the map ``{b"__ndarray__": True, b"data": <C-order bytes>, b"dtype": <dtype.str>,
  b"shape": <shape>}``; a numpy scalar is ``{b"__npgeneric__": True, b"data": <item>, b"dtype": ...}``;
  arrays of object, void or complex dtype cannot be sent;
- the server's first frame, on every connection, is the packed metadata map (``{}`` by default);
- each request is one binary frame holding the packed observation map; the reply is one binary frame
  (the packed map with ``actions``), or, when inference raised, a text frame with the traceback,
  after which the server closes the connection (code 1011);
- ``GET /healthz`` answers ``OK`` (readiness without a websocket).

This module imports neither conflictbench nor torch: the model environment's server uses it too.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

#: Request keys of openpi's LIBERO client (``examples/libero/main.py``).
IMAGE = "observation/image"
WRIST_IMAGE = "observation/wrist_image"
STATE = "observation/state"
PROMPT = "prompt"
#: Reply key holding the action chunk (horizon x 7).
ACTIONS = "actions"
#: Our one addition to a request: the seed of the episode's sampling noise at this step, an int in
#: [0, 2**63) (fits a signed 64-bit integer everywhere). openpi's own LIBERO input transform reads only
#: the four keys above, so its server ignores it; ours seeds with it.
NOISE_SEED = "conflictbench/noise_seed"
NOISE_SEED_LIMIT = 2**63

_UNSENDABLE_KINDS = "OVc"  # object, void (structured), complex


def _encode(value: Any) -> Any:
    if isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind in _UNSENDABLE_KINDS:
        raise TypeError(f"arrays of dtype {value.dtype} cannot be sent")
    if isinstance(value, np.ndarray):
        return {
            b"__ndarray__": True,
            b"data": np.ascontiguousarray(value).tobytes(),
            b"dtype": value.dtype.str,
            b"shape": value.shape,
        }
    if isinstance(value, np.generic):
        return {b"__npgeneric__": True, b"data": value.item(), b"dtype": value.dtype.str}
    return value


def _decode(obj: dict) -> Any:
    if b"__ndarray__" in obj:
        return np.ndarray(buffer=obj[b"data"], dtype=np.dtype(obj[b"dtype"]), shape=obj[b"shape"])
    if b"__npgeneric__" in obj:
        return np.dtype(obj[b"dtype"]).type(obj[b"data"])
    return obj


def packb(obj: Any) -> bytes:
    """``obj`` (maps, lists, strings, numbers, numpy arrays and scalars) as one openpi frame."""
    return msgpack.packb(obj, default=_encode)


def unpackb(data: bytes) -> Any:
    """The value in one openpi frame. Arrays come back read-only (they view the frame's bytes)."""
    return msgpack.unpackb(data, object_hook=_decode)
