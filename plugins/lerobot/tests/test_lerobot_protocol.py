"""The LeRobot plugin's wire at unit level: our client against our server on 127.0.0.1 with a numpy stand-in backend
(no model environment), what crosses it bit for bit, what the server refuses, and the client's checkpoint checks."""

from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosedError
from websockets.sync.client import connect

from conflictbench import UserError, sampling_seed
from conflictbench.core import Observation
from conflictbench.testing.plugin_tests import server_in_thread
from conflictbench_lerobot.checkpoints import CheckpointError, check_checkpoint
from conflictbench_lerobot.client import LeRobotConfig, load
from conflictbench_lerobot.protocol import (
    CAMERAS,
    EPISODE,
    NOISE_SEED,
    NOISE_SEED_LIMIT,
    PROMPT,
    ROBOT_STATE,
    STEP,
    image_key,
    packb,
    unpackb,
)
from conflictbench_lerobot.server import LeRobotPolicyServer


class StandInBackend:
    """Answers an action computed from every field of the request (float32, as LeRobot's policies answer)."""

    def __init__(self):
        self.requests: list[dict] = []
        self.metadata = {"policy_type": "act", "checkpoint_fingerprint": "sha256:standin"}

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]:
        self.requests.extend(requests)
        return [action_for(r) for r in requests]


def action_for(request: dict) -> np.ndarray:
    agent, wrist = (request[image_key(c)] for c in CAMERAS)
    features = [agent[0, 0, 0] / 255, wrist[-1, -1, 2] / 255, request["robot_state/eef/mat"][2, 1],
                request["robot_state/joints/vel"][6], len(request[PROMPT]) / 100, request[STEP] / 10,
                request[NOISE_SEED] % 1000 / 1000]  # fmt: skip
    return np.array([features], dtype=np.float32)


@contextmanager
def serving(backend):
    with server_in_thread(lambda: LeRobotPolicyServer(backend)) as (_server, port):
        yield f"ws://127.0.0.1:{port}"


def observation(step: int, size: int = 360, seed: int = 0) -> Observation:
    rng = np.random.default_rng(seed + step)
    return Observation(
        step=step,
        instruction="put the bowl on the plate",
        eef_pos=rng.normal(size=3),
        eef_quat=rng.normal(size=4),
        gripper_qpos=rng.normal(size=2),
        state=rng.normal(size=8),
        agentview_image=rng.integers(0, 256, (size, size, 3), dtype=np.uint8),
        wrist_image=rng.integers(0, 256, (size, size, 3), dtype=np.uint8),
        joint_positions=rng.normal(size=7),
        joint_velocities=rng.normal(size=7),
        gripper_qvel=rng.normal(size=2),
        eef_mat=rng.normal(size=(3, 3)),
        episode_id="episode-1",
        sampling_key="key-1",
    )


def test_the_raw_observation_crosses_bit_for_bit_and_the_action_comes_back_as_the_policy_gave_it():
    backend = StandInBackend()
    with serving(backend) as url:
        policy = load("lerobot", LeRobotConfig(server=url, checkpoint="standin", connect_retries=0))
        try:
            for step in range(3):
                obs = observation(step)
                actions = policy.act(obs)
                sent = backend.requests[-1]
                np.testing.assert_array_equal(actions, action_for(sent).astype(np.float64))
                # Both images exactly as the simulator rendered them (upside down: LeRobot's processors flip).
                assert sent[image_key(CAMERAS[0])].tobytes() == obs.agentview_image.tobytes()
                assert sent[image_key(CAMERAS[1])].tobytes() == obs.wrist_image.tobytes()
                given = {"robot_state/eef/pos": obs.eef_pos, "robot_state/eef/quat": obs.eef_quat,
                         "robot_state/eef/mat": obs.eef_mat, "robot_state/gripper/qpos": obs.gripper_qpos,
                         "robot_state/gripper/qvel": obs.gripper_qvel, "robot_state/joints/pos": obs.joint_positions,
                         "robot_state/joints/vel": obs.joint_velocities}  # fmt: skip
                assert set(given) == set(ROBOT_STATE)
                for key, value in given.items():
                    assert sent[key].dtype == np.float64 and sent[key].tobytes() == value.tobytes(), key
                assert sent[PROMPT] == obs.instruction and sent[EPISODE] == "episode-1" and sent[STEP] == step
                assert sent[NOISE_SEED] == sampling_seed(obs) % NOISE_SEED_LIMIT
                assert sent["lerobot/camera_name_mapping"] == {"agentview_image": "image",
                                                              "robot0_eye_in_hand_image": "image2"}  # fmt: skip
            assert (policy.image_size, policy.warmup_steps, policy.control_mode) == (360, 10, "relative")
            assert policy.max_steps == {"libero_spatial": 280, "libero_object": 280, "libero_goal": 300,
                                        "libero_10": 520, "libero_90": 400}  # fmt: skip
        finally:
            policy.close()


def valid_request() -> dict:
    backend = StandInBackend()
    with serving(backend) as url:
        policy = load("lerobot", LeRobotConfig(server=url, checkpoint="standin", connect_retries=0))
        try:
            return policy.encode(observation(0))
        finally:
            policy.close()


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: r.pop("robot_state/eef/mat"), "missing 'robot_state/eef/mat'"),
        (lambda r: r.update({image_key(CAMERAS[0]): r[image_key(CAMERAS[0])].astype(np.float32)}), "uint8 H x W x 3"),
        (lambda r: r.update({image_key(CAMERAS[1]): np.zeros((4, 4, 3), np.uint8)}), "one shape"),
        (lambda r: r.update({"robot_state/eef/pos": np.zeros(3, np.float32)}), "finite float64 array of shape (3,)"),
        (lambda r: r.update({"robot_state/joints/vel": np.full(7, np.nan)}), "finite float64"),
        (lambda r: r.update({PROMPT: "x" * 5000}), "at most 4096 characters"),
        (lambda r: r.update({STEP: -1}), "non-negative int"),
        (lambda r: r.update({NOISE_SEED: 2**63}), "an int in [0, 2**63)"),
        (lambda r: r.update({"lerobot/rename_map": {"a": 1}}), "a string of at most"),
        (lambda r: r.update({"lerobot/camera_name_mapping": {"agentview_image": "image"}}), "must name both"),
    ],
)
def test_a_request_that_is_not_a_valid_step_ends_its_connection_and_never_reaches_the_model(change, said):
    request = valid_request()
    change(request)
    backend = StandInBackend()
    with serving(backend) as url, connect(url, proxy=None) as connection:
        connection.recv()  # the metadata
        connection.send(packb(request))
        text = connection.recv()
        assert isinstance(text, str) and said in text, text
        with pytest.raises(ConnectionClosedError) as closed:
            connection.recv()
        assert closed.value.rcvd.code == 1011
    assert backend.requests == []


def test_an_object_array_in_a_frame_is_refused_before_it_is_built():
    frame = bytearray(packb({PROMPT: np.zeros(2, np.int64)}))
    frame = bytes(frame).replace(b"<i8", b"|O8")
    backend = StandInBackend()
    with serving(backend) as url, connect(url, proxy=None) as connection:
        connection.recv()
        connection.send(frame)
        text = connection.recv()
        assert "not an openpi msgpack frame" in text and "dtype" in text
    assert backend.requests == []
    assert unpackb(packb({"x": 1})) == {"x": 1}


def folder(tmp: Path, kind: str = "act", cameras=("image", "image2"), state=(8,), action=(7,), weights=True) -> Path:
    tmp.mkdir(parents=True, exist_ok=True)
    inputs = {f"observation.images.{c}": {"type": "VISUAL", "shape": [3, 256, 256]} for c in cameras}
    inputs["observation.state"] = {"type": "STATE", "shape": list(state)}
    outputs = {"action": {"type": "ACTION", "shape": list(action)}}
    config = {"type": kind, "input_features": inputs, "output_features": outputs}
    (tmp / "config.json").write_text(json.dumps(config))
    if weights:
        (tmp / "model.safetensors").write_bytes(b"")
    return tmp


DEFAULT = {"agentview_image": "image", "robot0_eye_in_hand_image": "image2"}


@pytest.mark.parametrize(
    ("make", "names", "renames", "said"),
    [
        (lambda t: folder(t, kind="no_such"), DEFAULT, {}, "a no_such policy, a type LeRobot 0.6.1 does not have"),
        (lambda t: folder(t, weights=False), DEFAULT, {}, "has no model.safetensors"),
        (
            lambda t: folder(t, cameras=("top", "wrist")),
            DEFAULT,
            {},
            "takes the cameras observation.images.top, "
            "observation.images.wrist; LIBERO gives observation.images.image, observation.images.image2",
        ),  # fmt: skip
        (
            lambda t: folder(t, state=(14,)),
            DEFAULT,
            {},
            "takes a state of shape [14]; LeRobot's LIBERO processors give the act policy [8]",
        ),  # fmt: skip
        (
            lambda t: folder(t, action=(14,)),
            DEFAULT,
            {},
            "answers actions of shape [14]; LeRobot's LIBERO post-processors take [7] of a act policy",
        ),  # fmt: skip
        (lambda t: folder(t, kind="xvla", state=(5,)), DEFAULT, {}, "take [20] of a xvla policy"),
    ],
)
def test_a_checkpoint_libero_cannot_feed_is_one_line_naming_what_was_expected_and_found(
    tmp_path, make, names, renames, said
):
    with pytest.raises(CheckpointError) as raised:
        check_checkpoint(make(tmp_path / "c"), names, renames)
    assert said in str(raised.value) and "\n" not in str(raised.value)


def test_camera_names_and_a_rename_map_make_other_cameras_fit_as_lerobot_eval_would(tmp_path):
    top = folder(tmp_path / "top", cameras=("top", "wrist"))
    renames = {"observation.images.image": "observation.images.top",
               "observation.images.image2": "observation.images.wrist"}  # fmt: skip
    assert check_checkpoint(top, DEFAULT, renames) == "act"
    named = {"agentview_image": "top", "robot0_eye_in_hand_image": "wrist"}
    assert check_checkpoint(top, named, {}) == "act"
    # LeRobot's own rule: either set of cameras may hold the other (one camera of LIBERO's two is fine).
    assert check_checkpoint(folder(tmp_path / "one", cameras=("image",)), DEFAULT, {}) == "act"


def test_bad_settings_are_user_errors_before_anything_starts(tmp_path):
    good = folder(tmp_path / "c")
    for settings, said in [
        ({"control_mode": "velocity"}, "model.control_mode must be relative or absolute"),
        ({"camera_name_mapping": "{not json"}, "model.camera_name_mapping must be a JSON map"),
        ({"camera_name_mapping": json.dumps({"agentview_image": "image"})}, "must name LIBERO's two cameras"),
        ({"rename_map": "[1, 2]"}, "model.rename_map must be a JSON map of names to names"),
        ({"render_size": 0}, "model.render_size must be >= 1"),
    ]:
        with pytest.raises(UserError, match=said.replace(".", r"\.").replace("(", r"\(")):
            load("lerobot", replace(LeRobotConfig(checkpoint=str(good)), **settings))
    with pytest.raises(UserError, match="takes the cameras"):
        load("lerobot", LeRobotConfig(checkpoint=str(folder(tmp_path / "d", cameras=("top", "side")))))


def test_the_maps_count_by_what_they_mean_and_the_batch_as_one_step():
    from conflictbench_lerobot.client import LeRobotConfig

    assert {"camera_name_mapping", "rename_map", "max_batch"} <= set(LeRobotConfig.identity_exempt)
    identities = []
    with serving(StandInBackend()) as url:
        for names, renames in (("", ""), (json.dumps(DEFAULT), "{}")):
            policy = load("lerobot", LeRobotConfig(server=url, checkpoint="standin", connect_retries=0,
                                                   camera_name_mapping=names, rename_map=renames))  # fmt: skip
            identities.append(policy.identity)
            policy.close()
    assert identities[0] == identities[1]
    assert identities[0]["max_batch"] == 1 and identities[0]["camera_names"] == DEFAULT


def test_readmes_settings_table_is_the_configs_defaults():
    """The plugin README's table of settings: every ``model.*`` row's default is ``LeRobotConfig``'s, and the budget
    it states is ``MAX_STEPS``."""
    import dataclasses
    import re

    from conflictbench_lerobot.client import MAX_STEPS

    readme = (Path(__file__).parents[1] / "README.md").read_text()
    rows = re.findall(r"^\| `model\.(\w+)` \| ([^|]+) \|", readme, flags=re.MULTILINE)
    defaults = {f.name: f.default for f in dataclasses.fields(LeRobotConfig)}
    assert len(rows) == 7
    for name, shown in rows:
        assert shown.strip().strip("`").strip('"') == str(defaults[name]).strip('"'), name
    budget = " / ".join(str(MAX_STEPS[s]) for s in ("libero_spatial", "libero_object", "libero_goal", "libero_10"))
    assert f"{budget}, libero_90 {MAX_STEPS['libero_90']}" in readme
