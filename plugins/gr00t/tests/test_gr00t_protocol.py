"""GR00T's wire format: byte-identical to NVIDIA's MsgSerializer (restated in the stand-in), and the request checks."""

from __future__ import annotations

import numpy as np
import pytest
from nvidia_standin_server import from_bytes, to_bytes

from conflictbench_gr00t.processing import gr00t_observation
from conflictbench_gr00t.protocol import (
    NOISE_SEED,
    InvalidRequest,
    get_action_request,
    packb,
    request_seed,
    unpackb,
    validate_observation,
)


def observation(instruction: str = "put the bowl on the plate") -> dict:
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (256, 256, 3), dtype=np.uint8) for _ in range(2)]
    return gr00t_observation(*images, np.linspace(-1, 1, 8), instruction)


def test_messages_are_byte_identical_to_nvidias_serializer_and_read_back_intact():
    request = get_action_request(observation(), seed=12345)
    assert packb(request) == to_bytes(request)
    for decoded in (unpackb(to_bytes(request)), from_bytes(packb(request))):
        sent = decoded["data"]["observation"]
        for key, value in request["data"]["observation"].items():
            if isinstance(value, np.ndarray):
                assert sent[key].dtype == value.dtype and np.array_equal(sent[key], value), key
            else:
                assert sent[key] == value
        assert decoded["data"]["options"] == {NOISE_SEED: 12345}


def test_numpy_scalars_travel_as_numbers_and_object_arrays_are_refused():
    assert unpackb(packb({"a": np.float32(1.5), "b": np.int64(3)})) == {"a": 1.5, "b": 3}
    with pytest.raises(TypeError, match="object dtype"):
        packb({"bad": np.array([object()])})


def test_a_request_without_a_seed_sends_options_none_as_nvidias_client_does():
    assert get_action_request({}, seed=None)["data"] == {"observation": {}, "options": None}
    assert "api_token" in get_action_request({}, api_token="t") and "api_token" not in get_action_request({})


def test_a_valid_observation_has_its_batch_size():
    assert validate_observation(observation()) == 1


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda o: o.pop("video.wrist_image"), "missing 'video.wrist_image'"),
        (lambda o: o.update({"video.image": o["video.image"][:, :, :224]}), "'video.image' must be uint8"),
        (lambda o: o.update({"state.x": o["state.x"].astype(np.float64)}), "'state.x' must be float32"),
        (lambda o: o.update({"state.gripper": o["state.gripper"][..., :1]}), "'state.gripper' must be float32"),
        (lambda o: o.update({"state.yaw": np.full((1, 1, 1), np.nan, np.float32)}), "'state.yaw' must be"),
        (lambda o: o.update({"annotation.human.action.task_description": "text"}), "must be a list of 1 strings"),
    ],
)
def test_malformed_observations_are_refused_naming_the_field(change, message):
    broken = observation()
    change(broken)
    with pytest.raises(InvalidRequest, match=message):
        validate_observation(broken)


def test_the_seed_in_options_is_read_and_checked():
    assert request_seed(None) is None and request_seed({}) is None and request_seed({NOISE_SEED: 7}) == 7
    for bad in (-1, 2**63, True, 1.5):
        with pytest.raises(InvalidRequest):
            request_seed({NOISE_SEED: bad})


def test_the_transport_and_codec_live_in_conflictbench_and_serving_and_stay_importable_here():
    from conflictbench.hosting.zeromq import ZmqTransport, answers_ping
    from conflictbench_gr00t import protocol, transport
    from conflictbench_serving import zeromq

    with pytest.warns(DeprecationWarning, match=r"conflictbench_gr00t\.transport\.Gr00tTransport .*hosting\.zeromq"):
        assert transport.Gr00tTransport is ZmqTransport
    with pytest.warns(DeprecationWarning, match=r"conflictbench_gr00t\.transport\.answers_ping .*0\.4\.0"):
        assert transport.answers_ping is answers_ping
    assert (protocol.packb, protocol.unpackb, protocol.InvalidRequest) == (
        zeromq.packb,
        zeromq.unpackb,
        zeromq.InvalidRequest,
    )
