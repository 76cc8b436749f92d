"""Each processing step of the OpenVLA family pinned to upstream's numbers (golden values worked out by hand)."""

from __future__ import annotations

import numpy as np
import pytest

from conflictbench.hosting import openvla_family as family
from conflictbench_openvla import processing


def test_the_prompt_lower_cases_the_task_into_openvlas_template():
    assert processing.prompt("Put the BOWL on the plate") == (
        "In: What action should the robot take to put the bowl on the plate?\nOut:"
    )


@pytest.mark.parametrize(
    "model_gripper, env_gripper",
    [(1.0, -1.0), (0.9, -1.0), (0.51, -1.0), (0.5, 0.0), (0.49, 1.0), (0.2, 1.0), (0.0, 1.0), (-0.3, 1.0)],
)
def test_the_gripper_is_signed_then_inverted_open_one_becomes_libero_minus_one(model_gripper, env_gripper):
    action = np.array([0.1, -0.2, 0.3, 0.01, 0.02, 0.03, model_gripper])
    out = family.env_gripper(action)
    assert out[6] == env_gripper
    np.testing.assert_array_equal(out[:6], action[:6])
    assert action[6] == model_gripper  # the reply is not changed in place (json-numpy's arrays are read-only)


def test_the_gripper_mapping_works_on_a_whole_chunk():
    chunk = np.array([[0.0] * 6 + [g] for g in (0.9, 0.2, 0.5)])
    assert family.env_gripper(chunk)[:, 6].tolist() == [-1.0, 1.0, 0.0]


@pytest.mark.parametrize(
    "setting, suite, key",
    [
        ("suite", "libero_goal", "libero_goal"),
        ("suite_no_noops", "libero_10", "libero_10_no_noops"),
        ("bridge_orig", "libero_goal", "bridge_orig"),
    ],
)
def test_unnorm_key_follows_the_episodes_suite_or_is_given(setting, suite, key):
    assert family.unnorm_key(setting, suite) == key


@pytest.mark.parametrize(
    "known, key",
    [
        ({"libero_goal_no_noops", "libero_10_no_noops"}, "libero_goal_no_noops"),  # only the no-op-filtered one
        ({"libero_goal", "libero_goal_no_noops"}, "libero_goal"),  # the suite's own first, as upstream
        ({"bridge_orig"}, "libero_goal"),  # neither: the suite's (the server then says what it has)
        (None, "libero_goal"),  # deploy.py does not say: as given
    ],
)
def test_the_suite_key_falls_back_to_no_noops_where_the_checkpoint_has_only_that(known, key):
    assert family.unnorm_key("suite", "libero_goal", known) == key
    assert family.unnorm_key("suite_no_noops", "libero_goal", known) == "libero_goal_no_noops"


def test_a_suite_key_without_a_suite_is_refused():
    with pytest.raises(ValueError, match="needs the episode's LIBERO suite"):
        family.unnorm_key("suite", "")


def test_256_bins_have_255_centres_from_minus_to_plus_254_over_255():
    centres = processing.bin_centers()
    assert centres.shape == (255,) and centres.dtype == np.float64
    assert centres[0] == pytest.approx(-1 + 1 / 255) and centres[254] == pytest.approx(1 - 1 / 255)
    assert centres[127] == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(np.diff(centres), 2 / 255)


@pytest.mark.parametrize(
    "token_id, centre_index",
    [(31999, 0), (31998, 1), (31872, 127), (31745, 254), (31744, 254), (31000, 254), (32000, 0), (32063, 0)],
)
def test_a_token_is_the_bin_vocab_size_minus_id_minus_one_clipped(token_id, centre_index):
    value = processing.detokenize(np.array([token_id]), vocab_size=32000)[0]
    assert value == processing.bin_centers()[centre_index]


def test_unnormalization_maps_minus_one_and_one_to_q01_and_q99_and_leaves_masked_dimensions():
    stats = {"q01": [-0.5, 0.0, 1.0], "q99": [0.5, 2.0, 3.0], "mask": [True, True, False]}
    out = family.unnormalize(np.array([[-1.0, 1.0, 0.7], [0.0, 0.0, -0.2]]), stats)
    np.testing.assert_allclose(out, [[-0.5, 2.0, 0.7], [0.0, 1.0, -0.2]])


def test_statistics_without_a_mask_unnormalize_every_dimension():
    out = family.unnormalize(np.array([1.0, -1.0]), {"q01": [0.0, 0.0], "q99": [2.0, 4.0]})
    np.testing.assert_allclose(out, [2.0, 0.0])


def test_ofts_unnormalization_adds_its_epsilon_to_the_range():
    stats = {"q01": [0.0], "q99": [0.0]}  # a constant dimension: OpenVLA gives q01, OFT q01 + 1e-8 at a = 1
    assert family.unnormalize(np.array([1.0]), stats)[0] == 0.0
    assert family.unnormalize(np.array([1.0]), stats, processing.OFT_EPSILON)[0] == 1e-8


def test_ofts_proprio_is_scaled_to_minus_one_one_and_clipped():
    stats = {"q01": [0.0, -1.0, 0.0], "q99": [2.0, 1.0, 1.0]}
    out = processing.normalize_proprio(np.array([1.0, 1.0, 5.0]), stats)
    np.testing.assert_allclose(out, [-5e-9, 1.0 - 1e-8, 1.0], atol=1e-15)  # 2 / (2 + 1e-8) - 1; 4 / (2 + 1e-8) - 1


def test_the_step_budgets_are_upstreams():
    assert processing.MAX_STEPS == {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
