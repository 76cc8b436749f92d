"""openpi's wire codec: msgpack with numpy arrays (openpi-client's ``msgpack_numpy``, PyPI 0.1.x).

- an array is the map ``{b"__ndarray__": True, b"data": <C-order bytes>, b"dtype": <dtype.str>,
  b"shape": <shape>}``; a numpy scalar is ``{b"__npgeneric__": True, b"data": <item>, b"dtype": ...}``;
- arrays of object, void or complex dtype cannot be sent (openpi refuses them too); one received is refused before
  it is built when it holds or hides objects or its bytes do not match its shape (:mod:`.arrays`: a frame naming
  an object dtype over its own bytes would otherwise be an array of pointers the sender chose).

openpi's servers and starVLA's (VLA-JEPA) use it; so do ours and the clients that talk to them.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

from .arrays import from_buffer, scalar

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
        return from_buffer(obj.get(b"data"), obj.get(b"dtype"), obj.get(b"shape"))
    if b"__npgeneric__" in obj:
        return scalar(obj.get(b"data"), obj.get(b"dtype"))
    return obj


def packb(obj: Any) -> bytes:
    """``obj`` (maps, lists, strings, numbers, numpy arrays and scalars) as one openpi frame."""
    return msgpack.packb(obj, default=_encode)


def unpackb(data: bytes) -> Any:
    """The value in one openpi frame. Arrays come back read-only (they view the frame's bytes); one that is
    refused raises :class:`~.arrays.UnsafeArray` (a ValueError)."""
    return msgpack.unpackb(data, object_hook=_decode)
