"""Arrays from a peer's bytes, checked before anything builds or looks at them: every protocol's decoder uses this.

A frame names an array's dtype and shape and carries its bytes; numpy builds whatever it is told over them. An
object dtype over a stranger's bytes is an array of pointers the stranger chose (printing it crashed a server); a
structured or void dtype can hide one, and a shape that does not match the bytes reads past them or makes a
zero-byte array of 10**18 elements. So, before an array exists:

- its dtype must be a plain one: booleans, numbers, bytes, text, dates (kinds :data:`SAFE_KINDS`), named by a
  string, with no fields and no sub-array, and elements of some size (numpy 1.26 wraps a huge itemsize such as
  ``'U1000000000'`` to a negative one);
- its shape must be a list of non-negative integers, at most :data:`MAX_DIMENSIONS` of them;
- the bytes must be exactly shape x itemsize;
- text (kind ``U``) must hold code points numpy can read back: none past U+10FFFF, no surrogate (numpy builds such
  an array, and reading it then raises SystemError).

A numpy scalar (msgpack-numpy's ``__npgeneric__``) must be of its dtype's kind and fit its itemsize: a number for
a numeric dtype, bytes or text no longer than the itemsize for ``S`` and ``U`` (``np.bytes_(10**9)`` would be a
gigabyte of zeros from a 39-byte frame).

Anything else raises :class:`UnsafeArray` (a ``ValueError``), which each server answers as an invalid request and
each client as a broken reply. The same rule reads msgpack-numpy (openpi), ``.npy`` bytes (GR00T's ZeroMQ) and
json-numpy (deploy.py's REST).
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
from typing import Any

import numpy as np
from numpy.lib import format as npy

#: dtype kinds an array from a peer may have: bool, signed, unsigned, float, complex, bytes, text, timedelta, date.
SAFE_KINDS = "biufcSUmM"
MAX_DIMENSIONS = 32  # numpy's own limit on old releases; no request needs more than 4


class UnsafeArray(ValueError):
    """An array a peer described that is refused (unsafe dtype, bad shape, size not matching its bytes)."""


def checked_dtype(spec: Any) -> np.dtype:
    """The dtype a peer named, if it is a plain one (see the module's rule); :class:`UnsafeArray` otherwise."""
    if isinstance(spec, bytes):
        spec = spec.decode("ascii", "replace")
    if not isinstance(spec, str):  # a list or a map names a structured dtype
        kind = type(spec).__name__
        raise UnsafeArray(f"an array's dtype must be a string (structured dtypes are refused), got {kind}")
    try:
        dtype = np.dtype(spec)
    except (TypeError, ValueError, SyntaxError) as error:
        raise UnsafeArray(f"not a dtype: {spec[:40]!r} ({error})") from None
    return _plain(dtype)


def _plain(dtype: np.dtype) -> np.dtype:
    if dtype.hasobject or dtype.kind not in SAFE_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise UnsafeArray(f"arrays of dtype {dtype.str!r} are refused (objects, structured and void types hide data)")
    if dtype.itemsize <= 0:  # 0, or negative where numpy 1.26 wrapped a huge one
        raise UnsafeArray(f"arrays of dtype {dtype.str!r} are refused (elements of no size)")
    return dtype


def _readable(array: np.ndarray) -> np.ndarray:
    """``array``, if its text (kind ``U``) holds only code points numpy can read back; :class:`UnsafeArray` else.
    Looked at as the 32-bit numbers numpy stores, never as text."""
    if array.dtype.kind == "U" and array.size:
        points = array.view(array.dtype.byteorder.replace("|", "=") + "u4")
        if int(points.max()) > 0x10FFFF or bool(((points >= 0xD800) & (points <= 0xDFFF)).any()):
            raise UnsafeArray(f"an array of dtype {array.dtype.str!r} holds code points that are not text")
    return array


def checked_shape(shape: Any, dtype: np.dtype, nbytes: int) -> tuple[int, ...]:
    """``shape`` as a tuple, if it is a list of non-negative integers whose product times the itemsize is
    ``nbytes``; :class:`UnsafeArray` otherwise."""
    if not isinstance(shape, (list, tuple)) or len(shape) > MAX_DIMENSIONS:
        raise UnsafeArray(f"an array's shape must be a list of at most {MAX_DIMENSIONS} sizes")
    if not all(isinstance(size, int) and not isinstance(size, bool) and size >= 0 for size in shape):
        raise UnsafeArray("an array's shape must hold non-negative integers")
    expected = math.prod(shape) * dtype.itemsize  # Python integers: no overflow
    if expected != nbytes:
        described = f"an array of shape {tuple(shape)} and dtype {dtype.str!r}"
        raise UnsafeArray(f"{described} needs {expected} bytes, got {nbytes}")
    return tuple(shape)


def from_buffer(data: Any, dtype_spec: Any, shape: Any) -> np.ndarray:
    """A read-only array viewing ``data`` (msgpack-numpy's ``__ndarray__``), checked first."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise UnsafeArray(f"an array's data must be bytes, got {type(data).__name__}")
    dtype = checked_dtype(dtype_spec)
    return _readable(np.ndarray(buffer=data, dtype=dtype, shape=checked_shape(shape, dtype, len(data))))


def scalar(item: Any, dtype_spec: Any) -> np.generic:
    """A numpy scalar of a plain dtype (msgpack-numpy's ``__npgeneric__``) from a msgpack number (numeric kinds),
    bytes (``S``) or text (``U``), never larger than the dtype's itemsize."""
    dtype = checked_dtype(dtype_spec)
    if dtype.kind == "S":
        fits = isinstance(item, bytes) and len(item) <= dtype.itemsize
    elif dtype.kind == "U":
        fits = isinstance(item, str) and len(item) <= dtype.itemsize // 4
    else:  # a number, of a fixed size whatever its value: never a text that numpy would parse
        fits = isinstance(item, (bool, int, float))
    if not fits:
        raise UnsafeArray(f"a {dtype.str!r} scalar cannot hold {type(item).__name__} data ({_preview(item)})")
    try:
        # built as an array of the declared dtype: a ``dtype.type(item)`` of bytes or text ignores the itemsize
        return np.array(item, dtype=dtype)[()] if dtype.kind in "SUmM" else dtype.type(item)
    except (TypeError, ValueError, OverflowError) as error:
        raise UnsafeArray(f"not a {dtype.str!r} scalar: {error}") from None


def _preview(item: Any) -> str:
    if isinstance(item, (bytes, str)):
        return f"{len(item)} long"
    return repr(item)[:40]


def load_npy(data: Any) -> np.ndarray:
    """The array in ``.npy`` bytes (GR00T's ``as_npy``), its header checked before the data is read."""
    if not isinstance(data, (bytes, bytearray)):
        raise UnsafeArray(f"an array's .npy data must be bytes, got {type(data).__name__}")
    stream = io.BytesIO(data)
    try:
        version = npy.read_magic(stream)
        read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
        shape, fortran_order, dtype = read_header(stream)
    except (ValueError, SyntaxError, TypeError) as error:
        raise UnsafeArray(f"not .npy data: {error}") from None
    dtype = _plain(dtype)
    checked_shape(list(shape), dtype, len(data) - stream.tell())
    return _readable(np.load(io.BytesIO(data), allow_pickle=False))


def json_numpy_loads(text: str | bytes) -> Any:
    """``json_numpy.loads``, each ``{"__numpy__": base64, "dtype": ..., "shape": [...]}`` checked before it is built
    (an empty shape gives the scalar, as json-numpy does). Raises ValueError for what is not json-numpy."""
    try:
        return json.loads(text, object_hook=_json_numpy_object)
    except RecursionError:  # a body of nothing but brackets: a bad request, not a server error
        raise ValueError("JSON nested too deeply") from None


def _json_numpy_object(obj: dict) -> Any:
    if "__numpy__" not in obj:
        return obj
    for key in ("dtype", "shape"):
        if key not in obj:
            raise UnsafeArray(f"a json-numpy array without its {key!r}")
    if not isinstance(obj["__numpy__"], str):
        raise UnsafeArray("a json-numpy array's data must be base64 text")
    try:
        data = base64.b64decode(obj["__numpy__"], validate=True)
    except (binascii.Error, ValueError) as error:
        raise UnsafeArray(f"a json-numpy array's data is not base64: {error}") from None
    dtype = checked_dtype(obj["dtype"])
    shape = checked_shape(obj["shape"], dtype, len(data))
    array = _readable(np.frombuffer(data, dtype).reshape(shape))
    return array if shape else array[()]
