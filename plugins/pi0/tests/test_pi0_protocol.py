"""openpi's wire format: our codec and openpi-client's own read each other's frames exactly."""

from __future__ import annotations

import numpy as np
import pytest
from openpi_client import msgpack_numpy

from conflictbench_pi0.protocol import packb, unpackb

REQUEST = {
    "observation/image": np.arange(224 * 224 * 3, dtype=np.uint8).reshape(224, 224, 3),
    "observation/state": np.linspace(-1, 1, 8),
    "prompt": "put the bowl on the plate",
    "conflictbench/noise_seed": 2**64 - 1,
    "nested": {"chunk": np.ones((10, 7), dtype=np.float32), "scalar": np.float32(0.5), "n": np.int64(-3)},
}


def assert_same(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert_same(a[key], b[key])
    elif isinstance(a, (np.ndarray, np.generic)):
        assert type(a) is type(b) and a.dtype == b.dtype and np.shape(a) == np.shape(b)
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b and type(a) is type(b)


def test_openpi_reads_our_frames_and_we_read_openpis():
    assert_same(msgpack_numpy.unpackb(packb(REQUEST)), REQUEST)
    assert_same(unpackb(msgpack_numpy.Packer().pack(REQUEST)), REQUEST)


def test_our_frames_are_byte_identical_to_openpis():
    assert packb(REQUEST) == msgpack_numpy.Packer().pack(REQUEST)


def test_a_non_contiguous_array_is_sent_in_c_order():
    image = np.arange(24, dtype=np.uint8).reshape(2, 4, 3)[::-1, ::-1]  # a rotated view, as LIBERO's images are
    np.testing.assert_array_equal(unpackb(packb({"x": image}))["x"], image)


@pytest.mark.parametrize("value", [np.array([object()]), np.zeros(2, dtype=complex), np.zeros(2, dtype="V4")])
def test_arrays_openpi_cannot_carry_are_refused(value):
    with pytest.raises(TypeError, match="cannot be sent"):
        packb({"x": value})


def test_the_transport_lives_in_conflictbench_and_stays_importable_here():
    from conflictbench.hosting.openpi import OpenpiTransport

    with pytest.warns(DeprecationWarning, match=r"conflictbench_pi0\.transport\.OpenpiTransport .*hosting\.openpi"):
        from conflictbench_pi0.transport import OpenpiTransport as former

    assert former is OpenpiTransport
