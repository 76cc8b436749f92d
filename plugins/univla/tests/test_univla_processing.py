"""UniVLA's history prompt and temporal ensembling pinned to upstream's numbers (worked out by hand)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conflictbench_univla import processing
from conflictbench_univla.processing import TemporalEnsemble


def test_latent_token_ids_become_act_tokens_joined_without_separator():
    assert processing.history_text([32004, 32013, 32001, 32008]) == "<ACT_3><ACT_12><ACT_0><ACT_7>"


def test_the_prompt_gains_the_history_only_once_there_is_one():
    assert processing.prompt("Put the BOWL", "") == "In: What action should the robot take to put the bowl?\nOut:"
    assert processing.prompt("Put the BOWL", "<ACT_1><ACT_2><ACT_3><ACT_4>") == (
        "In: What action should the robot take to put the bowl? History action <ACT_1><ACT_2><ACT_3><ACT_4>\nOut:"
    )


def chunk(query: int, window: int = 12) -> np.ndarray:
    """A chunk whose entry for step j of query q is 100 q + j (all seven dimensions)."""
    return np.repeat((100.0 * query + np.arange(window))[:, None], 7, axis=1)


def test_the_first_query_executes_its_own_first_action():
    np.testing.assert_array_equal(TemporalEnsemble().add(chunk(0)), np.zeros(7))


def test_later_queries_average_what_each_chunk_planned_for_now_newest_weighted_most():
    ensemble = TemporalEnsemble()
    ensemble.add(chunk(0))
    second = ensemble.add(chunk(1))  # chunk 1 step 0 (100) with weight 1, chunk 0 step 1 (1) with e^-0.1
    assert second[0] == pytest.approx((100 + 1 * math.exp(-0.1)) / (1 + math.exp(-0.1)), rel=1e-15)
    third = ensemble.add(chunk(2))  # 200, 101, 2
    weights = [1, math.exp(-0.1), math.exp(-0.2)]
    assert third[0] == pytest.approx((200 * weights[0] + 101 * weights[1] + 2 * weights[2]) / sum(weights), rel=1e-15)


def test_a_chunk_stops_counting_once_it_has_no_plan_for_now():
    ensemble = TemporalEnsemble(window=3)
    for query in range(3):
        ensemble.add(chunk(query, 3))
    fourth = ensemble.add(chunk(3, 3))  # chunk 0 planned steps 0..2 only: now chunks 1 (step 2), 2 (1), 3 (0)
    weights = [1, math.exp(-0.1), math.exp(-0.2)]
    assert fourth[0] == pytest.approx((300 * weights[0] + 201 * weights[1] + 102 * weights[2]) / sum(weights))


def test_reset_forgets_the_window():
    ensemble = TemporalEnsemble()
    ensemble.add(chunk(5))
    ensemble.reset()
    np.testing.assert_array_equal(ensemble.add(chunk(0)), np.zeros(7))


def test_the_weights_are_exp_of_minus_one_tenth_per_query_of_age():
    np.testing.assert_allclose(TemporalEnsemble().weights[:, 0], np.exp(-0.1 * np.arange(12)))


def test_a_chunk_of_another_window_is_refused():
    with pytest.raises(ValueError, match=r"expected a chunk of shape \(12, 7\)"):
        TemporalEnsemble().add(np.zeros((8, 7)))


def test_the_step_budgets_are_upstreams():
    assert processing.UNIVLA_MAX_STEPS == {
        "libero_spatial": 240,
        "libero_object": 300,
        "libero_goal": 320,
        "libero_10": 550,
    }
