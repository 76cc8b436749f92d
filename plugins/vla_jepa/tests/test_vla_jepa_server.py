"""Our VLA-JEPA server's protocol with a numpy stand-in backend (real websocket on 127.0.0.1), upstream's
client codec, our client reading the statistics from its metadata, and the serve command's user errors."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from jepa_standin import ACTION_STATS
from openpi_client import msgpack_numpy as upstream_codec
from websockets.exceptions import ConnectionClosedError
from websockets.sync.client import connect

from conflictbench import UserError
from conflictbench.testing import camera_observation
from conflictbench.testing.plugin_tests import check_serve_refuses, lerobot_checkpoint_errors, server_in_thread
from conflictbench_vla_jepa.client import VlaJepaConfig, load
from conflictbench_vla_jepa.processing import ActionStatistics, camera_image, env_actions
from conflictbench_vla_jepa.protocol import Row, infer_request
from conflictbench_vla_jepa.server import JepaPolicyServer

PLUGIN_ROOT = Path(__file__).resolve().parents[1]
CHUNK = 5


class StandInBackend:
    """Normalized chunks that follow every field of a row; records each call's rows."""

    def __init__(self):
        self.calls: list[list[Row]] = []
        self.metadata = {"policy_type": "vla_jepa", "checkpoint_fingerprint": "sha256:standin",
                         "chunk_length": CHUNK, "action_statistics": ACTION_STATS}  # fmt: skip

    def infer_batch(self, rows: list[Row]) -> list[np.ndarray]:
        self.calls.append(rows)
        if any("fail" in row.instruction for row in rows):
            raise RuntimeError("the model failed on purpose")
        return [chunk_for(row) for row in rows]


def chunk_for(row: Row) -> np.ndarray:
    features = [row.image.mean() / 255, row.wrist_image[:, :112].mean() / 255, row.state[0], len(row.instruction) / 99,
                (row.seed or 0) % 1000 / 1000, row.state[7]]  # fmt: skip
    return np.array([[*(np.array(features) * (t + 1) / CHUNK), (0.2, 0.9)[t % 2]] for t in range(CHUNK)], np.float32)


@contextmanager
def serving(backend, max_batch: int = 2):
    with server_in_thread(lambda: JepaPolicyServer(backend, max_batch)) as (_server, port):
        yield f"ws://127.0.0.1:{port}"


def ask(connection, message) -> dict:
    connection.send(upstream_codec.Packer().pack(message))
    return upstream_codec.unpackb(connection.recv())


def request(step: int = 0, instruction: str = "put the bowl on the plate", seed: int = 11) -> dict:
    obs = camera_observation(step, instruction)
    images = [camera_image(obs.agentview_image), camera_image(obs.wrist_image)]
    return infer_request(images, instruction, obs.state, f"r{step}", None, seed)


def test_upstreams_envelope_ping_infer_errors_in_frame_and_the_connection_stays_open():
    backend = StandInBackend()
    with serving(backend) as url, connect(url, proxy=None) as connection:
        metadata = upstream_codec.unpackb(connection.recv())
        assert metadata["max_batch"] == 2 and metadata["fixed_shape"] is True and metadata["chunk_length"] == CHUNK
        assert ask(connection, {"type": "ping", "request_id": "p"}) == {
            "status": "ok", "ok": True, "type": "ping", "request_id": "p"}  # fmt: skip
        reply = ask(connection, request(3))
        assert reply["status"] == "ok" and reply["type"] == "inference_result" and reply["request_id"] == "r3"
        row = backend.calls[-1][0]
        assert row.seed == 11 and row.state.shape == (8,) and row.image.shape == (224, 224, 3)
        np.testing.assert_array_equal(reply["data"]["normalized_actions"], chunk_for(row)[None])
        assert len(backend.calls[-1]) == 2  # padded to the fixed shape
        bad = request(1)
        bad["payload"]["state"] = [np.zeros((1, 7))]
        for message, fragment in [
            ({"type": "train"}, "Unsupported message type 'train'"),
            (bad, "row 0: 'state' must be 8 finite numbers"),
            (request(2, "fail here"), "RuntimeError: the model failed on purpose"),
        ]:
            answer = ask(connection, message)
            assert answer["status"] == "error" and answer["ok"] is False and fragment in answer["error"]["message"]
        assert ask(connection, request(4))["status"] == "ok"  # the same connection goes on


def test_rows_of_one_payload_are_answered_in_order_and_a_non_map_ends_the_connection():
    backend = StandInBackend()
    first, second = request(1, seed=5), request(2, "open the drawer", seed=5)
    both = dict(first)
    both["payload"] = {**first["payload"], **{key: first["payload"][key] + second["payload"][key]
                                              for key in ("batch_images", "instructions", "state")}}  # fmt: skip
    with serving(backend) as url, connect(url, proxy=None) as connection:
        connection.recv()
        chunks = ask(connection, both)["data"]["normalized_actions"]
        assert chunks.shape == (2, CHUNK, 7)
        assert [row.instruction for row in backend.calls[-1]] == ["put the bowl on the plate", "open the drawer"]
        np.testing.assert_array_equal(chunks[1], chunk_for(backend.calls[-1][1]))
        connection.send(upstream_codec.Packer().pack([1, 2]))
        assert "binary msgpack map" in connection.recv()
        with pytest.raises(ConnectionClosedError):
            connection.recv()


def test_our_client_takes_the_statistics_and_chunk_length_from_our_servers_metadata():
    backend = StandInBackend()
    with serving(backend, max_batch=1) as url:
        policy = load("vla-jepa", VlaJepaConfig(server=url, checkpoint="ignored", connect_retries=0))
        try:
            obs = camera_observation(5)
            actions = policy.act(obs)
            expected = env_actions(chunk_for(backend.calls[-1][0]), ActionStatistics.from_mapping(ACTION_STATS), CHUNK)
            np.testing.assert_array_equal(actions, expected)  # the float32 chunk the server sent, un-normalized
            assert policy.identity == {"checkpoint": "sha256:standin", "max_batch": 1, "model_stack": "unreported"}
        finally:
            policy.close()


def test_a_chunk_length_beyond_what_our_server_sends_is_a_user_error():
    with serving(StandInBackend(), max_batch=1) as url:
        with pytest.raises(UserError, match=f"model.chunk_length=6 is more than the {CHUNK} actions"):
            load("vla-jepa", VlaJepaConfig(server=url, checkpoint="x", chunk_length=6, connect_retries=0))


@pytest.mark.parametrize(
    "make, fragment",
    lerobot_checkpoint_errors("vla_jepa", "pi05", "not a LeRobot checkpoint (no config.json) (a VLA-JEPA"),
)
def test_serve_command_user_errors_are_one_line_and_exit_2(tmp_path, make, fragment):
    check_serve_refuses(PLUGIN_ROOT, tmp_path, "vla-jepa", make(tmp_path), fragment)


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({}, None),
        ({"clip_normalized_actions": False}, "sets clip_normalized_actions=False; the VLA-JEPA client does True"),
        ({"gripper_threshold": 0.3}, "sets gripper_threshold=0.3"),
        ({"normalization_mapping": {"ACTION": "MEAN_STD"}}, "normalizes actions with MEAN_STD"),
    ],
)
def test_a_checkpoint_post_processing_otherwise_than_the_client_is_refused(change, fragment):
    """The client restates LeRobot's default postprocessing; a checkpoint configured otherwise would have its
    actions un-normalized wrongly and scored as its behaviour."""
    from types import SimpleNamespace

    from conflictbench_vla_jepa.backend import CLIENT_POSTPROCESSING, CheckpointError, check_postprocessing

    config = SimpleNamespace(**CLIENT_POSTPROCESSING, normalization_mapping={"ACTION": "MIN_MAX"})
    for name, value in change.items():
        setattr(config, name, value)
    if fragment is None:
        check_postprocessing(Path("ckpt"), config)
        return
    with pytest.raises(CheckpointError, match=fragment):
        check_postprocessing(Path("ckpt"), config)
