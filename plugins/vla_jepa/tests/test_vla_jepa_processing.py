"""VLA-JEPA's LIBERO client steps, each pinned (facts: VLA-JEPA's ``examples/LIBERO/`` client)."""

from __future__ import annotations

import numpy as np
import pytest
from jepa_standin import ACTION_STATS, write_run
from PIL import Image

from conflictbench_vla_jepa.processing import (
    MAX_STEPS,
    ActionStatistics,
    StatisticsError,
    camera_image,
    chunk_length_from_config,
    env_actions,
    unnormalize,
)

STATS = ActionStatistics.from_mapping(ACTION_STATS)


def test_a_camera_is_turned_upright_then_area_resized_to_224():
    rendered = np.zeros((256, 256, 3), np.uint8)
    rendered[128:] = 200  # LIBERO's render: the bottom half is the scene's top
    sent = camera_image(rendered)
    assert sent.shape == (224, 224, 3) and sent.dtype == np.uint8
    assert sent[:100].min() == 200 and sent[124:].max() == 0  # upright
    noise = np.random.default_rng(0).integers(0, 256, (256, 256, 3), dtype=np.uint8)
    upright = noise[::-1, ::-1].astype(np.float64)
    weights = area_weights(256, 224)
    area = np.stack([weights @ upright[:, :, c] @ weights.T for c in range(3)], axis=2)
    got = camera_image(noise).astype(np.float64)
    assert np.abs(got - area).max() <= 0.5 + 1e-9  # each pixel the mean of the source area it covers, rounded
    bilinear = np.asarray(Image.fromarray(np.ascontiguousarray(noise[::-1, ::-1])).resize((224, 224), Image.BILINEAR))
    assert np.abs(bilinear - area).max() > 10  # which a bilinear resize would not be


def area_weights(source: int, target: int) -> np.ndarray:
    """(target, source): the share of source pixel k in target pixel i when each covers source/target pixels."""
    scale, weights = source / target, np.zeros((target, source))
    for i in range(target):
        start, end = i * scale, (i + 1) * scale
        for k in range(int(start), min(source, int(np.ceil(end)))):
            weights[i, k] = max(0.0, min(end, k + 1) - max(start, k)) / scale
    return weights


def test_unnormalize_clips_thresholds_the_gripper_and_maps_min_max_where_the_mask_says():
    normalized = np.array([[-1.0, 0.0, 1.0, 2.0, -2.0, 0.5, 0.49], [0.2, -0.2, 0.0, 0.0, 0.0, 0.0, 0.5]])
    got = unnormalize(normalized, STATS)
    low, high = np.array(ACTION_STATS["min"]), np.array(ACTION_STATS["max"])
    first = 0.5 * (np.array([-1.0, 0.0, 1.0, 1.0, -1.0, 0.5]) + 1) * (high[:6] - low[:6]) + low[:6]
    np.testing.assert_allclose(got[0, :6], first)
    assert got[0, 6] == 0.0 and got[1, 6] == 1.0  # gripper: below 0.5 -> 0, from 0.5 -> 1; masked out of min/max


def test_env_actions_take_the_chunk_length_and_map_the_gripper_to_liberos_sign():
    normalized = np.zeros((8, 7))
    normalized[:, 6] = [0.1, 0.9, 0.5, 0.49, 0.0, 1.0, 0.7, 0.2]
    actions = env_actions(normalized, STATS, chunk_length=7)
    assert actions.shape == (7, 7)
    assert actions[:, 6].tolist() == [1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0]  # open (1) -> -1, closed (0) -> +1
    masked_gripper = ActionStatistics(STATS.low, STATS.high, np.ones(7, bool))  # min/max on the gripper too
    assert env_actions(normalized, masked_gripper, 2)[:, 6].tolist() == [1.0, -1.0]
    with pytest.raises(ValueError, match="expected at least \\(9, 7\\)"):
        env_actions(normalized, STATS, chunk_length=9)


def test_statistics_come_from_the_runs_file_and_the_chunk_length_from_its_config(tmp_path):
    path = write_run(tmp_path / "run", window=7)
    stats = ActionStatistics.from_file(path)
    np.testing.assert_array_equal(stats.high, ACTION_STATS["max"])
    assert stats.mask.tolist() == ACTION_STATS["mask"]
    assert chunk_length_from_config(path.parent / "config.yaml") == 8
    two = write_run(tmp_path / "two", datasets={"a": {"action": ACTION_STATS}, "b": {"action": ACTION_STATS}})
    with pytest.raises(StatisticsError, match="choose one with model.unnorm_key \\(a, b\\)"):
        ActionStatistics.from_file(two)
    assert ActionStatistics.from_file(two, "b").low.tolist() == ACTION_STATS["min"]
    with pytest.raises(StatisticsError, match="no action statistics for 'c'"):
        ActionStatistics.from_file(two, "c")


def test_vla_jepas_step_budgets():
    assert MAX_STEPS == {"libero_spatial": 250, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
