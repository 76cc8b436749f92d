"""What the vla-jepa client sends and executes is, bit for bit, what VLA-JEPA's own LIBERO client does.

The other side of each comparison is ``upstream_vla_jepa.py``: upstream's client (ginwind/VLA-JEPA@ec8c70f,
``examples/LIBERO/eval_libero.py`` and ``model2libero_interface.py``) restated from its source, line by line, by a
reader who had not read our processing code. Ours is reached through the code a run executes: the observation a
worker makes (``make_observation``), the policy's ``encode``, the wire codec, the policy's ``decode`` and the check
every chunk passes before ``env.step`` (``as_action_chunk``).
"""

from __future__ import annotations

import numpy as np
import pytest
import upstream_vla_jepa as upstream
from jepa_standin import ACTION_STATS, start_standin, write_run
from starvla_standin_server import normalized_for

from conflictbench.core.policy import as_action_chunk
from conflictbench.testing import worker_observation
from conflictbench_vla_jepa.client import VlaJepaConfig, load
from conflictbench_vla_jepa.protocol import NOISE_SEED, packb, unpackb

WINDOW = 7  # future_action_window_size: 8 actions a query
CONFIG = {"framework": {"action_model": {"future_action_window_size": WINDOW}}}
HALF = np.float32(0.5)

# Statistics as a run's dataset_statistics.json holds them: starVLA's (gripper masked out), none masked (the
# gripper's un-normalized value is then (min + max) / 2 or max), and one where that midpoint lies between 0.5 and
# the next float32 above it: float64 arithmetic calls it above 0.5, upstream's float32 cast calls it 0.5.
STATISTICS = {
    "starvla": ACTION_STATS,
    "unmasked": {"min": [-0.9, -0.8, -0.7, -0.2, -0.3, -0.4, -1.0], "max": [0.9, 0.7, 0.9, 0.25, 0.35, 0.3, 1.0]},
    "rotation-masked": {  # a dimension left normalized: the mask must pick per dimension
        "min": [-0.9, -0.8, -0.7, -0.2, -0.3, -0.4, 0.0],
        "max": [0.9, 0.7, 0.9, 0.25, 0.35, 0.3, 1.0],
        "mask": [True, True, True, True, False, True, False],
    },
    "gripper-at-half": {
        "min": [-0.937, -0.93, -0.94, -0.12, -0.17, -0.21, 0.0],
        "max": [0.937, 0.87, 0.94, 0.19, 0.21, 0.36, 1.0000000001],
    },
}


def replies(seed: int) -> list[np.ndarray]:
    """(1, 8, 7) float32 chunks as a server sends them (one of 16 rows, more than a query executes): at and past
    the bounds, the gripper around 0.5, and values in between."""
    rng = np.random.default_rng(seed)
    edges = np.array([-1.5, -1.0, np.nextafter(-1.0, 0), 0.0, np.nextafter(HALF, 0), HALF, np.nextafter(HALF, 1),
                      np.nextafter(1.0, 0), 1.0, 2.0], dtype=np.float32)  # fmt: skip
    chunks = [rng.uniform(-1.2, 1.2, size=(1, WINDOW + 1, 7)).astype(np.float32) for _ in range(5)]
    chunks.append(rng.uniform(-1.2, 1.2, size=(1, 16, 7)).astype(np.float32))  # longer than the chunk executed
    chunks.append(rng.choice(edges, size=(1, WINDOW + 1, 7)).astype(np.float32))
    gripper = rng.uniform(-1, 1, size=(1, WINDOW + 1, 7)).astype(np.float32)
    gripper[0, :, 6] = edges[4:7].repeat(3)[: WINDOW + 1]
    chunks.append(gripper)
    return chunks


def bits(actions) -> np.ndarray:
    """The float64 bit patterns of actions as env.step receives them (robosuite makes a float64 array)."""
    return np.asarray(actions, dtype=np.float64).view(np.uint64)


@pytest.fixture(scope="module")
def standin(tmp_path_factory):
    server, url = start_standin(tmp_path_factory.mktemp("standin"))
    yield url
    server.stop()


def policy_with(statistics: dict, folder, url: str):
    stats = write_run(folder, window=WINDOW, datasets={"libero": {"action": statistics}})
    return load("vla-jepa", VlaJepaConfig(server=url, checkpoint="stand-in", stats=str(stats), connect_retries=0))


def raw_observation(seed: int, w: float | None = None) -> dict:
    """A LIBERO observation as ``OffScreenRenderEnv`` returns it: 256-px renders with structure and noise, the
    state in float64 (``w`` fixes the quaternion's real part)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:256, 0:256]
    images = {}
    for camera in ("agentview", "robot0_eye_in_hand"):
        base = np.stack([x * 0.9 + 10 * seed, y * 0.7, (x + y) * 0.4], axis=-1)
        images[f"{camera}_image"] = np.clip(base + rng.normal(0, 12, base.shape), 0, 255).astype(np.uint8)
    quat = rng.normal(size=4)
    if w is not None:
        quat[3] = 0.0
        quat[:3] *= np.sqrt(max(0.0, 1.0 - w * w)) / np.linalg.norm(quat[:3])
        quat[3] = w
    else:
        quat /= np.linalg.norm(quat)
    return {
        **images,
        "robot0_eef_pos": rng.uniform(-0.3, 1.2, 3),
        "robot0_eef_quat": quat,
        "robot0_gripper_qpos": np.array([0.039, -0.039]) * rng.uniform(0.1, 1.0),
        "robot0_joint_pos": rng.uniform(-2, 2, 7),
    }


def observation_of(raw: dict, text: str, step: int = 0):
    return worker_observation(raw, text, suite="libero_goal", step=step, episode_id="e0")


@pytest.mark.parametrize("name", sorted(STATISTICS))
def test_every_executed_action_is_upstreams_bit_for_bit(name, standin, tmp_path):
    policy = policy_with(STATISTICS[name], tmp_path / name, standin)
    dataset_statistics = {"libero": {"action": STATISTICS[name]}}
    obs = observation_of(raw_observation(0), "put the bowl on the plate")
    try:
        for seed in range(3):
            for reply_array in replies(seed):
                reply = {"status": "ok", "ok": True, "type": "inference_result", "request_id": "e0/0",
                         "data": {"normalized_actions": reply_array}}  # fmt: skip
                received = unpackb(packb(reply))  # as the transport hands it to decode: float32, read-only
                ours = as_action_chunk(policy.decode(received, obs))
                theirs = upstream.executed(unpackb(packb(reply)), dataset_statistics, config=CONFIG)
                assert len(ours) == len(theirs) == WINDOW + 1
                np.testing.assert_array_equal(bits(ours), bits(theirs), err_msg=f"{name}, reply seed {seed}")
    finally:
        policy.close()


def test_a_float64_reply_is_followed_in_float64_as_upstream_does(standin, tmp_path):
    policy = policy_with(STATISTICS["unmasked"], tmp_path / "run", standin)
    obs = observation_of(raw_observation(1), "open the drawer")
    try:
        reply_array = replies(5)[0].astype(np.float64) + 1e-9  # a server answering float64
        reply = {"data": {"normalized_actions": reply_array}}
        ours = as_action_chunk(policy.decode(unpackb(packb(reply)), obs))
        theirs = upstream.executed(reply, {"libero": {"action": STATISTICS["unmasked"]}}, config=CONFIG)
        np.testing.assert_array_equal(bits(ours), bits(theirs))
    finally:
        policy.close()


TEXTS = ("pick up the black bowl between the plate and the ramekin and place it on the plate",
         "  Put the Bowl on the STOVE.  Before you act, check that the task is possible.\n")  # fmt: skip


@pytest.mark.parametrize("w, text", [(None, TEXTS[0]), (1.0, TEXTS[1]), (-0.3, TEXTS[0]), (0.999999999, TEXTS[1]),
                                     (1.0000001, TEXTS[0]), (-1.0000001, TEXTS[1])])  # fmt: skip
def test_the_request_is_upstreams_payload_plus_the_noise_seed(w, text, standin, tmp_path):
    policy = policy_with(ACTION_STATS, tmp_path / "run", standin)
    raw = raw_observation(2, w)
    try:
        message = policy.encode(observation_of(raw, text, step=8))
        theirs = upstream.request({k: np.array(v) for k, v in raw.items()}, text)
    finally:
        policy.close()
    ours = message["payload"]
    assert [key for key in ours if key != NOISE_SEED] == list(theirs)  # the same keys, in the same order
    for ours_image, their_image in zip(ours["batch_images"][0], theirs["batch_images"][0], strict=True):
        assert ours_image.dtype == their_image.dtype == np.uint8 and ours_image.shape == their_image.shape
        assert ours_image.tobytes() == their_image.tobytes()
    (ours_state,), (their_state,) = ours["state"], theirs["state"]
    assert ours_state.dtype == their_state.dtype and ours_state.shape == their_state.shape == (1, 8)
    np.testing.assert_array_equal(ours_state.view(np.uint64), their_state.view(np.uint64))
    for key in ("instructions", "unnorm_key", "do_sample", "use_ddim", "num_ddim_steps"):
        assert ours[key] == theirs[key] and type(ours[key]) is type(theirs[key]), key
    # And on the wire: the message encode made, less our two additions (the seed and the request id, each after
    # upstream's keys), packs to upstream's bytes: the envelope's keys and order are upstream's too.
    assert list(message) == ["payload", "type", "request_id"]
    without_ours = {**{k: v for k, v in message.items() if k != "request_id"},
                    "payload": {k: v for k, v in ours.items() if k != NOISE_SEED}}  # fmt: skip
    assert packb(without_ours) == upstream.pack(upstream.infer_message(theirs))


def test_a_whole_query_against_a_server_executes_upstreams_actions(standin, tmp_path):
    """End to end: the stand-in server's reply to our request, executed by ours and by upstream's steps."""
    policy = policy_with(ACTION_STATS, tmp_path / "run", standin)
    obs = observation_of(raw_observation(3), "put the cream cheese in the bowl", step=16)
    try:
        payload = policy.encode(obs)["payload"]
        ours = as_action_chunk(policy.act(obs))
    finally:
        policy.close()
    reply = {"data": {"normalized_actions": normalized_for(payload, chunk=WINDOW + 1)}}
    theirs = upstream.executed(reply, {"libero": {"action": ACTION_STATS}}, config=CONFIG)
    np.testing.assert_array_equal(bits(ours), bits(theirs))
