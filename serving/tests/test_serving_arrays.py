"""Every protocol's decoder refuses arrays that hold objects, hide them (structured, void) or lie about their size,
before the array exists: msgpack-numpy (openpi), .npy (GR00T's ZeroMQ), json-numpy (deploy.py's REST)."""

from __future__ import annotations

import base64
import io
import json

import msgpack
import numpy as np
import pytest

from conflictbench_serving import arrays, msgpack_numpy, zeromq
from conflictbench_serving.arrays import UnsafeArray

# (dtype as a peer names it, shape, data bytes): each must be refused
BAD_ARRAYS = {
    "object": ("|O", [2], b"\x41" * 16),
    "object 0-d": ("|O", [], b"\x41" * 8),
    "void": ("|V8", [2], b"\x41" * 16),
    "structured": ([["a", "<f8"]], [2], b"\x41" * 16),
    "structured with an object": ([["a", "|O"]], [2], b"\x41" * 16),
    "sub-array": ("(2,)<f8", [1], b"\x41" * 16),
    "too few bytes": ("<f8", [3], b"\x41" * 16),
    "too many bytes": ("<f8", [1], b"\x41" * 16),
    "negative shape": ("<f8", [-2], b""),
    "empty elements": ("|S0", [10**18], b""),
    "not a shape": ("<f8", "2", b"\x41" * 16),
    "not a dtype": ("not-a-dtype", [2], b"\x41" * 16),
    # numpy 1.26 wraps this itemsize to a negative number: with no elements it matched its 0 bytes
    "negative itemsize": ("<U1000000000", [0], b""),
    # code points past U+10FFFF: numpy builds the array, and reading it then raises SystemError
    "text past U+10FFFF": ("<U1", [2], b"\xff" * 8),
    "text with a surrogate": ("<U1", [1], (0xD800).to_bytes(4, "little")),
}


def _msgpack_frame(dtype, shape, data) -> bytes:
    return msgpack.packb({"x": [{b"__ndarray__": True, b"data": data, b"dtype": dtype, b"shape": shape}]})


def _npy(dtype, shape, data) -> bytes:
    """.npy bytes with the header a peer chose."""
    buffer = io.BytesIO()
    descr = dtype if isinstance(dtype, str) else [tuple(field) for field in dtype]
    header = {"descr": descr, "fortran_order": False, "shape": tuple(shape) if isinstance(shape, list) else shape}
    np.lib.format.write_array_header_1_0(buffer, header)
    return buffer.getvalue() + data


def _json_numpy(dtype, shape, data) -> str:
    return json.dumps({"x": {"__numpy__": base64.b64encode(data).decode(), "dtype": dtype, "shape": shape}})


@pytest.mark.parametrize("case", BAD_ARRAYS.values(), ids=BAD_ARRAYS.keys())
def test_msgpack_numpy_refuses_the_array_before_building_it(case):
    with pytest.raises(UnsafeArray):
        msgpack_numpy.unpackb(_msgpack_frame(*case))


@pytest.mark.parametrize("case", BAD_ARRAYS.values(), ids=BAD_ARRAYS.keys())
def test_zeromq_refuses_the_array_before_reading_it(case):
    dtype, shape, data = case
    try:
        npy = _npy(dtype, shape, data)
    except (ValueError, TypeError):
        pytest.skip("numpy cannot even write this header")
    with pytest.raises(UnsafeArray):
        zeromq.unpackb(msgpack.packb({"x": {"__ndarray_class__": True, "as_npy": npy}}))


@pytest.mark.parametrize("case", BAD_ARRAYS.values(), ids=BAD_ARRAYS.keys())
def test_json_numpy_refuses_the_array_before_building_it(case):
    with pytest.raises(UnsafeArray):
        arrays.json_numpy_loads(_json_numpy(*case))


@pytest.mark.parametrize("dtype", ["|O", "|V8", "|V1000000000000", "<U1000000000"])
def test_msgpack_numpy_refuses_unsafe_scalars(dtype):
    with pytest.raises(UnsafeArray):
        msgpack_numpy.unpackb(msgpack.packb({b"__npgeneric__": True, b"data": 10**12, b"dtype": dtype}))


def _scalar(data, dtype) -> bytes:
    return msgpack.packb({b"__npgeneric__": True, b"data": data, b"dtype": dtype})


def test_a_scalar_is_no_larger_than_its_declared_dtype():
    frame = _scalar(10**9, "|S1")  # np.bytes_(10**9) is a gigabyte of zeros: the pi server went to 3.95 GB
    assert len(frame) <= 39
    with pytest.raises(UnsafeArray, match="'|S1'"):
        msgpack_numpy.unpackb(frame)


@pytest.mark.parametrize(
    ("data", "dtype"),
    [(b"abc", "|S1"), ("abc", "<U1"), (5, "|S8"), (b"ab", "<U2"), ("7", "<i8"), (b"7", "<f4"), ([1], "<f8")],
)
def test_a_scalar_must_be_of_its_dtype_kind_and_fit_its_itemsize(data, dtype):
    with pytest.raises(UnsafeArray):
        msgpack_numpy.unpackb(_scalar(data, dtype))


def test_scalars_of_every_plain_kind_still_read():
    for value in (np.int32(-7), np.float32(0.5), np.bool_(True), np.uint8(3), np.int64(-2)):
        back = msgpack_numpy.unpackb(msgpack_numpy.packb(value))
        assert back == value and back.dtype == value.dtype, value
    # bytes and text scalars (msgpack sends numpy's as plain bytes and str; another sender may name their dtype),
    # shorter than the itemsize or as long
    assert msgpack_numpy.unpackb(_scalar(b"ab", "|S3")) == np.bytes_(b"ab")
    assert msgpack_numpy.unpackb(_scalar("h\u00e9", "<U2")) == np.str_("h\u00e9")


def test_text_arrays_of_either_byte_order_still_read():
    for dtype in ("<U3", ">U3"):
        array = np.array(["a", "h\u00e9", "\U0010ffff"], dtype)
        np.testing.assert_array_equal(msgpack_numpy.unpackb(msgpack_numpy.packb(array)), array)


def test_the_refusal_says_what_was_refused():
    with pytest.raises(UnsafeArray, match="dtype '\\|O'.*refused"):
        msgpack_numpy.unpackb(_msgpack_frame("|O", [2], b"\x41" * 16))
    with pytest.raises(UnsafeArray, match="needs 24 bytes, got 16"):
        msgpack_numpy.unpackb(_msgpack_frame("<f8", [3], b"\x41" * 16))


GOOD = {
    "image": np.arange(224 * 224 * 3, dtype=np.uint8).reshape(224, 224, 3),
    "state": np.linspace(-1, 1, 8),
    "chunk": np.ones((50, 32), np.float32),
    "bools": np.array([True, False]),
    "text": np.array(["a", "bc"]),
    "empty": np.zeros((0, 7)),
    "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)),
}


def test_every_codec_still_reads_what_the_protocols_carry():
    back = msgpack_numpy.unpackb(msgpack_numpy.packb({**GOOD, "seed": np.int64(7), "f": np.float32(0.5)}))
    assert back["seed"] == 7 and back["seed"].dtype == np.int64 and back["f"].dtype == np.float32
    through_zmq = zeromq.unpackb(zeromq.packb(GOOD))
    json_numpy = pytest.importorskip("json_numpy")
    through_json = arrays.json_numpy_loads(json_numpy.dumps({**GOOD, "scalar": np.float32(2.5)}))
    assert through_json["scalar"] == 2.5 and isinstance(through_json["scalar"], np.float32)
    for decoded in (back, through_zmq, through_json):
        for key, value in GOOD.items():
            assert decoded[key].dtype == value.dtype
            np.testing.assert_array_equal(decoded[key], value)
    assert through_zmq["image"].flags.writeable  # GR00T's arrays come back writable, as np.load gives them


def test_deep_nesting_is_a_bad_message_in_every_codec():
    with pytest.raises(ValueError, match="nested too deeply"):
        arrays.json_numpy_loads("[" * 100_000 + "]" * 100_000)
    for unpackb in (msgpack_numpy.unpackb, zeromq.unpackb):
        with pytest.raises(ValueError):
            unpackb(b"\x91" * 100_000 + b"\xc0")
