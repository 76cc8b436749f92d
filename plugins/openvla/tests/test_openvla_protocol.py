"""deploy.py's wire format: json-numpy bodies, as upstream's ``json_numpy.patch()``-ed FastAPI reads and writes them."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from conflictbench import InfrastructureError
from conflictbench_openvla.protocol import (
    JsonNumpyTransport,
    oft_request,
    openvla_request,
    read_action,
    read_chunk,
)


def test_an_openvla_body_carries_the_image_as_json_numpys_base64_of_its_bytes():
    image = np.arange(224 * 224 * 3, dtype=np.uint8).reshape(224, 224, 3)
    body = json.loads(JsonNumpyTransport("http://h:8000").dumps(openvla_request(image, "Do It", "libero_goal")))
    assert set(body) == {"image", "instruction", "unnorm_key"}
    assert body["instruction"] == "Do It" and body["unnorm_key"] == "libero_goal"  # the server lower-cases
    assert body["image"]["dtype"] == "|u1" and body["image"]["shape"] == [224, 224, 3]
    assert base64.b64decode(body["image"]["__numpy__"]) == image.tobytes()


def test_an_oft_body_carries_both_images_and_the_raw_state_as_float64():
    full, wrist = np.zeros((224, 224, 3), np.uint8), np.ones((224, 224, 3), np.uint8)
    state = np.array([0.1, 0.2, 1.0, 3.1, 0.1, -0.2, 0.04, -0.03])
    body = json.loads(JsonNumpyTransport("http://h:8777").dumps(oft_request(full, wrist, state, "go")))
    assert list(body) == ["full_image", "wrist_image", "state", "instruction"]
    assert body["state"]["dtype"] == "<f8" and body["state"]["shape"] == [8]
    assert np.frombuffer(base64.b64decode(body["state"]["__numpy__"]), "<f8").tolist() == state.tolist()
    assert base64.b64decode(body["wrist_image"]["__numpy__"]) == wrist.tobytes()


def test_replies_decode_to_writable_float64_arrays():
    action = np.linspace(-1, 1, 7)
    text = json.dumps({"__numpy__": base64.b64encode(action.tobytes()).decode(), "dtype": "<f8", "shape": [7]})
    decoded = read_action(JsonNumpyTransport("http://h").loads(text.encode()))
    assert decoded.tolist() == action.tolist() and decoded.flags.writeable
    chunk = [{"__numpy__": base64.b64encode((action * i).tobytes()).decode(), "dtype": "<f8", "shape": [7]}
             for i in range(8)]  # fmt: skip
    assert read_chunk(JsonNumpyTransport("http://h").loads(json.dumps(chunk).encode())).shape == (8, 7)


def test_deploys_error_string_is_an_infrastructure_error():
    with pytest.raises(InfrastructureError, match='answered "error".*log has the traceback'):
        JsonNumpyTransport("http://h:8000").loads(b'"error"')


@pytest.mark.parametrize(
    "body", [b'{"__numpy__": "AAAA", "shape": [7]}', b'{"__numpy__": "AAAA", "dtype": "<x9", "shape": [1]}']
)
def test_a_json_numpy_array_that_cannot_be_read_is_an_unreadable_reply(body):
    with pytest.raises(ValueError, match="a json-numpy array that cannot be read"):  # the transport: infrastructure
        JsonNumpyTransport("http://h:8000").loads(body)


@pytest.mark.parametrize("reply", [[1.0, 2.0], "oops", {"a": 1}])
def test_a_reply_that_is_no_action_is_refused(reply):
    with pytest.raises(ValueError):
        read_action(reply)


@pytest.mark.parametrize("reply", [[], "oops", [[1.0, 2.0]]])
def test_a_reply_that_is_no_chunk_is_refused(reply):
    with pytest.raises(ValueError):
        read_chunk(reply)


@pytest.mark.parametrize(
    "given, used",
    [
        ("http://h:8000", "http://h:8000/act"),
        ("http://h:8000/", "http://h:8000/act"),
        ("http://h:9/x/act", "http://h:9/x/act"),
    ],
)
def test_a_url_without_a_path_gets_deploys_route(given, used):
    assert JsonNumpyTransport(given).url == used


def test_the_family_steps_and_transport_live_in_conflictbench_and_their_former_names_warn():
    from conflictbench.hosting import openvla_family, rest
    from conflictbench_openvla import images, processing, protocol

    assert protocol.JsonNumpyTransport is rest.JsonNumpyTransport
    moved = [(images, "policy_image"), (images, "center_crop")]
    moved += [(processing, name) for name in ("env_gripper", "unnorm_key", "unnormalize", "SUITE_KEYS")]
    for module, name in moved:
        with pytest.warns(DeprecationWarning, match=rf"{module.__name__}\.{name} .*hosting\.openvla_family"):
            assert getattr(module, name) is getattr(openvla_family, name)


@pytest.mark.parametrize("body", [b'{"image": {"__numpy__": "AAAA", "shape": [7]}, "instruction": "x"}', b"[1, 2"])
def test_the_server_answers_a_body_it_cannot_read_with_an_invalid_request(body):
    from conflictbench_openvla.server import request_row
    from conflictbench_serving.rest import InvalidRequest

    with pytest.raises(InvalidRequest, match="not a json-numpy body") as refused:  # a 400 with the message
        request_row(body)
    assert "\n" not in str(refused.value)
