"""GR00T's LIBERO client steps, each pinned (facts: Isaac-GR00T's ``gr00t/eval/sim/LIBERO/libero_env.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from conflictbench_gr00t.processing import env_actions, gr00t_observation
from conflictbench_gr00t.protocol import ACTION_KEYS, LANGUAGE_KEY, STATE_KEYS


def rendered(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (256, 256, 3), dtype=np.uint8)


def test_both_cameras_are_turned_upright_and_sent_at_the_rendered_256_pixels_with_batch_and_time_axes():
    agentview, wrist = rendered(1), rendered(2)
    observation = gr00t_observation(agentview, wrist, np.zeros(8), "x")
    for key, image in (("video.image", agentview), ("video.wrist_image", wrist)):
        sent = observation[key]
        assert sent.dtype == np.uint8 and sent.shape == (1, 1, 256, 256, 3)
        assert np.array_equal(sent[0, 0, 0, 0], image[255, 255])  # top-left pixel was the bottom-right one
        assert np.array_equal(sent[0, 0], np.rot90(image, 2))


def test_the_8d_state_is_split_by_name_position_axis_angle_and_both_gripper_joints():
    state = np.array([0.1, 0.2, 0.3, 1.1, 1.2, 1.3, 0.04, -0.039])
    observation = gr00t_observation(rendered(1), rendered(2), state, "x")
    for index, key in enumerate(STATE_KEYS[:-1]):
        assert observation[key].dtype == np.float32 and observation[key].shape == (1, 1, 1)
        assert observation[key][0, 0, 0] == np.float32(state[index]), key
    assert observation["state.gripper"].shape == (1, 1, 2)
    assert np.array_equal(observation["state.gripper"][0, 0], np.float32(state[6:]))


def test_the_task_text_goes_as_it_is_in_a_list_under_the_annotation_key():
    observation = gr00t_observation(rendered(1), rendered(2), np.zeros(8), "Put the bowl on the plate.")
    assert observation[LANGUAGE_KEY] == ["Put the bowl on the plate."]


def test_actions_are_concatenated_in_key_order_and_the_gripper_maps_from_0_1_open_to_liberos_sign():
    horizon = 6
    reply = {key: np.full((1, horizon, 1), 0.1 * (i + 1), np.float32) for i, key in enumerate(ACTION_KEYS)}
    reply["action.gripper"] = np.array([0.0, 1.0, 0.5, 0.2, 0.9, 0.51], np.float32)[None, :, None]
    chunk = env_actions(reply)
    assert chunk.shape == (horizon, 7)
    np.testing.assert_allclose(chunk[:, :6], np.tile(np.float32([0.1, 0.2, 0.3, 0.4, 0.5, 0.6]), (horizon, 1)))
    # 2g - 1, sign, times -1: dataset 0 (closed) -> +1 (LIBERO close), 1 (open) -> -1, exactly 0.5 -> 0
    assert chunk[:, 6].tolist() == [1.0, -1.0, 0.0, 1.0, -1.0, -1.0]


def test_a_reply_missing_a_key_or_with_mixed_horizons_is_refused():
    reply = {key: np.zeros((1, 4, 1), np.float32) for key in ACTION_KEYS}
    with pytest.raises(ValueError, match="no action.gripper"):
        env_actions({k: v for k, v in reply.items() if k != "action.gripper"})
    with pytest.raises(ValueError, match="horizons"):
        env_actions({**reply, "action.x": np.zeros((1, 3, 1), np.float32)})
    with pytest.raises(ValueError, match="expected \\(B, T, 1\\)"):
        env_actions({**reply, "action.y": np.zeros((4, 1), np.float32)})
