"""Process measures (TAR, TS, Early20 TS, AMS) against values worked out by hand from DESIGN.md."""

from __future__ import annotations

import math

import numpy as np
import pytest
from testing_support import episode_record

import conflictbench
from conflictbench.core import EpisodeRecord, Pair, Plugins, hookimpl
from conflictbench.metrics import dtw, evaluate_pairs, pair_metrics, plain

SIGMA = 0.10


def record(eef=None, actions=None, targets=None, names=("bowl",), case="c1", **kw) -> EpisodeRecord:
    """An episode whose arrays are given directly (positions as x-only lists allowed)."""
    eef = np.zeros((1, 3)) if eef is None else np.asarray(eef, dtype=float)
    if eef.ndim == 1:  # x coordinates only
        eef = np.stack([eef, np.zeros_like(eef), np.zeros_like(eef)], axis=1)
    h = len(eef) - 1
    actions = np.zeros((h, 7)) if actions is None else np.asarray(actions, dtype=float)
    targets = np.zeros((len(eef), len(names), 3)) if targets is None else np.asarray(targets, dtype=float)
    arrays = dict(eef_pos=eef, actions=actions, target_pos=targets, target_names=tuple(names))
    return episode_record(**{"suite": "libero_spatial", "case_id": case, **arrays, **kw})


def line(x):
    return np.stack([np.asarray(x, float), np.zeros(len(x)), np.zeros(len(x))], axis=1)


# -- DTW ------------------------------------------------------------------------------------------
KERNELS = ("matrix", "lex", "plain")


@pytest.mark.parametrize("kernel", KERNELS)
def test_dtw_cost_and_path_length_by_hand(kernel):
    # P = 0, 1, 1 and Q = 0, 0.1, 1 on the x axis. Local costs |P_i - Q_j|:
    #   i=0: 0   0.1  1
    #   i=1: 1   0.9  0
    #   i=2: 1   0.9  0
    # (0,0)->(0,1)->(1,2)->(2,2) costs 0 + 0.1 + 0 + 0 = 0.1 over 4 cells; the diagonal costs 0.9,
    # every other path more. So DTW = 0.1 and L = 4 (an optimal path need not be the shortest one).
    cost, cells = dtw(line([0, 1, 1]), line([0, 0.1, 1]), kernel=kernel)
    assert cost == pytest.approx(0.1, abs=1e-15)
    assert cells == 4


@pytest.mark.parametrize("kernel", KERNELS)
def test_dtw_tie_picks_the_shortest_minimum_cost_path(kernel):
    # P = 0, 1 and Q = 1, 1: c(0,0)=1, c(0,1)=1, c(1,0)=0, c(1,1)=0.
    # Diagonal (0,0)->(1,1): 1 + 0 = 1 in 2 cells; (0,0)->(1,0)->(1,1): 1 + 0 + 0 = 1 in 3 cells;
    # (0,0)->(0,1)->(1,1): 2. Two optimal paths tie at cost 1: L is the shorter, 2.
    assert dtw(line([0, 1]), line([1, 1]), kernel=kernel) == (1.0, 2)
    assert dtw(line([1, 1]), line([0, 1]), kernel=kernel) == (1.0, 2)  # symmetric


@pytest.mark.parametrize("kernel", KERNELS)
def test_dtw_single_point_and_euclidean_cost(kernel):
    # one point against three: the only path visits every column: 0 + 1 + 2 = 3, L = 3
    assert dtw(line([0]), line([0, 1, 2]), kernel=kernel) == (3.0, 3)
    # Euclidean, not per-axis: (0,0,0) to (0.3,0.4,0) is 0.5
    cost, cells = dtw(np.zeros((1, 3)), np.array([[0.3, 0.4, 0.0]]), kernel=kernel)
    assert cost == pytest.approx(0.5, abs=1e-15) and cells == 1


def test_dtw_empty_is_undefined():
    cost, cells = dtw(np.zeros((0, 3)), line([0, 1]))
    assert math.isnan(cost) and cells == 0


def test_dtw_kernels_agree_bit_for_bit_with_the_plain_definition():
    rng = np.random.default_rng(7)
    for trial in range(150):
        n, m = rng.integers(1, 13, size=2)
        if trial % 2:  # integer grid: many equal-cost paths, so the tie rule decides L
            p, q = rng.integers(0, 3, size=(n, 3)) * 0.5, rng.integers(0, 3, size=(m, 3)) * 0.5
        else:
            p, q = rng.normal(size=(n, 3)), rng.normal(size=(m, 3))
        expected = plain.dtw(p, q)
        assert dtw(p, q, kernel="matrix") == expected
        assert dtw(p, q, kernel="lex") == expected
        assert dtw(q, p) == expected


# -- TS and Early20 TS ----------------------------------------------------------------------------
def test_ts_is_exp_of_dtw_over_sigma_and_path_length():
    ref, con = record(eef=line([0, 1, 1]), case=None), record(eef=line([0, 0.1, 1]))
    # DTW 0.1 over L = 4 cells (see the DTW test): TS = exp(-0.1 / (0.1 * 4)) = exp(-0.25)
    assert pair_metrics(ref, con)["ts"] == pytest.approx(math.exp(-0.25), rel=1e-12)
    ref, con = record(eef=line([0, 1]), case=None), record(eef=line([1, 1]))
    assert pair_metrics(ref, con)["ts"] == pytest.approx(math.exp(-1 / (SIGMA * 2)), rel=1e-12)


def test_identical_paths_have_ts_one_and_undefined_when_not_finite_or_empty():
    path = line(np.linspace(0, 0.3, 31))
    assert pair_metrics(record(eef=path, case=None), record(eef=path.copy()))["ts"] == 1.0
    broken = path.copy()
    broken[5, 1] = np.nan
    assert pair_metrics(record(eef=path, case=None), record(eef=broken))["ts"] is None
    empty = record(eef=np.zeros((0, 3)), actions=np.zeros((0, 7)), targets=np.zeros((0, 1, 3)))
    values = pair_metrics(record(eef=path, case=None), empty)
    assert values["ts"] is None and values["early20_ts"] is None


def test_early20_uses_the_initial_position_and_the_first_20_steps():
    ref = line(np.arange(31) * 0.01)  # H = 30
    later = ref.copy()
    later[21:, 2] += 1.0  # differs only after the 21st action
    m = pair_metrics(record(eef=ref, case=None), record(eef=later))
    assert m["early20_ts"] == 1.0 and m["ts"] < 1.0
    at20 = ref.copy()
    at20[20, 2] = 0.5  # the position after the 20th action is inside the window
    # diagonal of zero costs, then the mandatory last cell (20, 20) costs exactly 0.5; any detour
    # adds cost, so DTW = 0.5 over L = 21 cells
    m = pair_metrics(record(eef=ref, case=None), record(eef=at20))
    assert m["early20_ts"] == pytest.approx(math.exp(-0.5 / (SIGMA * 21)), rel=1e-12)


def test_early20_with_fewer_than_20_steps_uses_every_position():
    rng = np.random.default_rng(3)
    ref, con = rng.normal(size=(6, 3)) * 0.05, rng.normal(size=(9, 3)) * 0.05  # H = 5 and H = 8
    m = pair_metrics(record(eef=ref, case=None), record(eef=con))
    assert m["early20_ts"] == m["ts"]
    # and with H = 30 against H = 8: the reference's first 21 positions against all 9
    long_ref = rng.normal(size=(31, 3)) * 0.05
    m = pair_metrics(record(eef=long_ref, case=None), record(eef=con))
    cost, cells = plain.dtw(con, long_ref[:21])
    assert m["early20_ts"] == pytest.approx(math.exp(-cost / (SIGMA * cells)), rel=1e-12)


# -- TAR ------------------------------------------------------------------------------------------
def _approach_record(distances, case="c1", names=("bowl",)):
    """End effector on the x axis at these distances from a target fixed at the origin."""
    eef = line(distances)
    return record(eef=eef, targets=np.zeros((len(eef), len(names), 3)), names=names, case=case)


def test_tar_by_hand():
    # reference: d = 0.5, 0.3, 0.1, 0.2 -> A+ = 0.5 - 0.1 = 0.4
    # conflict:  d = 0.5, 0.4, 0.3, 0.6 -> A- = 0.5 - 0.3 = 0.2 -> TAR = 0.2 / 0.4 = 0.5
    ref = _approach_record([0.5, 0.3, 0.1, 0.2], case=None)
    con = _approach_record([0.5, 0.4, 0.3, 0.6])
    assert pair_metrics(ref, con)["tar"] == pytest.approx(0.5, rel=1e-12)
    # moving away only: A- = max(0.5 - 0.5, 0) = 0 -> TAR 0
    assert pair_metrics(ref, _approach_record([0.5, 0.7, 0.9]))["tar"] == 0.0
    # approaching closer than the reference: 0.45 / 0.4 clipped to 1
    assert pair_metrics(ref, _approach_record([0.5, 0.05]))["tar"] == 1.0


def test_tar_takes_the_nearest_target_at_each_state():
    # two targets at x = 0 and x = 1; eef at x = 0.5, 0.9, 0.5: d = 0.5, 0.1, 0.5 (nearest switches)
    targets = np.zeros((3, 2, 3))
    targets[:, 1, 0] = 1.0
    ref = record(eef=line([0.5, 0.9, 0.5]), targets=targets, names=("a", "b"), case=None)  # A+ = 0.4
    con = record(eef=line([0.5, 0.3, 0.5]), targets=targets, names=("b", "a"))  # d = .5,.3,.5: A- = 0.2
    assert pair_metrics(ref, con)["tar"] == pytest.approx(0.5, rel=1e-12)  # same set, other order


def test_tar_is_undefined_where_the_reference_approached_by_less_than_a_centimetre():
    """DESIGN.md's guard: with A+ near 0 the ratio is noise (a motionless reference gave 100 %, or 0 %)."""
    for reference in ([0.5, 0.6, 0.7], [0.5, 0.5], [0.5, 0.491]):  # A+ = 0, 0, 0.009 m
        ref = _approach_record(reference, case=None)
        for conflict in ([0.5, 0.5], [0.5, 0.3]):
            assert pair_metrics(ref, _approach_record(conflict))["tar"] is None
            assert plain.tar(ref, _approach_record(conflict)) is None
    ref = _approach_record([0.5, 0.48], case=None)  # A+ = 0.02: defined
    assert pair_metrics(ref, _approach_record([0.5, 0.49]))["tar"] == pytest.approx(0.5, rel=1e-9)
    assert pair_metrics(ref, _approach_record([0.5, 0.5]))["tar"] == 0.0


def test_tar_undefined_for_other_targets_no_target_or_non_finite():
    ref = _approach_record([0.5, 0.1], case=None)
    assert pair_metrics(ref, _approach_record([0.5, 0.3], names=("plate",)))["tar"] is None
    assert pair_metrics(ref, _approach_record([0.5, 0.3], names=("bowl", "plate")))["tar"] is None
    none = record(eef=line([0.5, 0.3]), targets=np.zeros((2, 0, 3)), names=())
    assert (
        pair_metrics(record(eef=line([0.5, 0.1]), targets=np.zeros((2, 0, 3)), names=(), case=None), none)["tar"]
        is None
    )
    bad = _approach_record([0.5, 0.3])
    bad.target_pos[1, 0, 2] = np.inf
    assert pair_metrics(ref, bad)["tar"] is None


# -- AMS ------------------------------------------------------------------------------------------
def _actions(rows):
    return np.asarray(rows, dtype=float)


def test_ams_by_hand():
    # reference moves 0.1 along dim 0 at every step: gamma = (0.1, 1e-4 x 5) (sqrt of eps elsewhere),
    # I+ = mean ||(1, 0, ...)|| = 1. Conflict 0.05 along dim 0: I- = 0.5 -> AMS = 0.5.
    ref = record(eef=line([0, 0, 0, 0, 0]), actions=_actions([[0.1, 0, 0, 0, 0, 0, 1]] * 4), case=None)
    con = record(eef=line([0, 0, 0]), actions=_actions([[0.05, 0, 0, 0, 0, 0, -1]] * 2))
    assert pair_metrics(ref, con)["ams"] == pytest.approx(0.5, rel=1e-12)
    # the gripper (7th dim) is left out: changing it changes nothing
    gripper = record(eef=line([0, 0, 0]), actions=_actions([[0.05, 0, 0, 0, 0, 0, 7.0], [0.05, 0, 0, 0, 0, 0, -3]]))
    assert pair_metrics(ref, gripper)["ams"] == pytest.approx(0.5, rel=1e-12)
    # a dim the reference never used is scaled by sqrt(eps) = 1e-4: 1e-4 there counts as 1 -> AMS 0
    side = record(eef=line([0, 0]), actions=_actions([[0, 1e-4, 0, 0, 0, 0, 0]]))
    assert pair_metrics(ref, side)["ams"] == pytest.approx(0.0, abs=1e-9)
    # moving more than the reference: 1 - 2 = -1 clipped to 0; not moving at all: 1
    assert pair_metrics(ref, record(eef=line([0, 0]), actions=_actions([[0.2, 0, 0, 0, 0, 0, 0]])))["ams"] == 0.0
    assert pair_metrics(ref, record(eef=line([0, 0]), actions=np.zeros((1, 7))))["ams"] == 1.0


def test_ams_gamma_is_the_reference_rms_per_dim():
    # dim 0 alternates 0.3 and -0.1: gamma_0 = sqrt((0.09 + 0.01) / 2) = sqrt(0.05)
    # I+ = mean(0.3, 0.1) / sqrt(0.05) = 0.2 / sqrt(0.05); conflict 0.1 each step: I- = 0.1 / sqrt(0.05)
    # AMS = 1 - 0.1 / 0.2 = 0.5
    ref = record(eef=line([0, 0, 0]), actions=_actions([[0.3, 0, 0, 0, 0, 0, 0], [-0.1, 0, 0, 0, 0, 0, 0]]), case=None)
    con = record(eef=line([0, 0, 0, 0]), actions=_actions([[0.1, 0, 0, 0, 0, 0, 0]] * 3))
    assert pair_metrics(ref, con)["ams"] == pytest.approx(0.5, rel=1e-12)


def test_ams_undefined_when_reference_intensity_is_below_eps_or_actions_are_empty():
    still = record(eef=line([0, 0, 0]), actions=np.zeros((2, 7)), case=None)  # I+ = 0
    con = record(eef=line([0, 0]), actions=_actions([[0.1, 0, 0, 0, 0, 0, 0]]))
    assert pair_metrics(still, con)["ams"] is None
    tiny = record(eef=line([0, 0]), actions=_actions([[1e-13, 0, 0, 0, 0, 0, 0]]), case=None)
    # gamma = sqrt(max(1e-26, eps)) = 1e-4: I+ = 1e-9 <= eps
    assert pair_metrics(tiny, con)["ams"] is None
    moving = record(eef=line([0, 0]), actions=_actions([[0.1, 0, 0, 0, 0, 0, 0]]), case=None)
    assert pair_metrics(moving, record(eef=line([0])))["ams"] is None  # H = 0 conflict


def test_zero_step_rollouts():
    # H = 0 on both sides: one state each, no action.
    ref, con = record(eef=line([0.5]), case=None), record(eef=line([0.5]))
    m = pair_metrics(ref, con)
    assert m["ts"] == 1.0 and m["early20_ts"] == 1.0  # one cell, cost 0
    assert m["tar"] is None  # A+ = 0: the reference did not approach (the guard)
    assert m["ams"] is None  # no actions


# -- the batch path and the registry ---------------------------------------------------------------
def _random_record(rng, case, h=None, k=2):
    h = int(rng.integers(0, 45)) if h is None else h
    eef = np.cumsum(rng.normal(size=(h + 1, 3)) * 0.02, axis=0)
    if rng.random() < 0.3:  # repeated positions: a policy standing still
        eef[h // 2 :] = eef[h // 2]
    targets = eef[:, None, :] + rng.normal(size=(h + 1, k, 3)) * 0.1
    return record(
        eef=eef,
        actions=rng.normal(size=(h, 7)) * 0.2,
        targets=targets,
        names=tuple(f"o{i}" for i in range(k)),
        case=case,
        success=bool(rng.random() < 0.5),
    )


def test_batch_path_matches_the_plain_formulas_pair_by_pair():
    rng = np.random.default_rng(11)
    refs = [_random_record(rng, None) for _ in range(6)]
    refs.append(record(eef=line([0.1]), case=None))  # H = 0
    cons = [_random_record(rng, f"c{i}") for i in range(40)]
    cons[3].eef_pos[1, 0] = np.nan
    references = [refs[i % len(refs)] for i in range(len(cons))]  # references reused
    frame = evaluate_pairs(references, cons, chunk_size=7)
    assert len(frame) == len(cons)
    defined = 0
    for i, (ref, con) in enumerate(zip(references, cons)):
        expected = plain.pair_metrics(ref, con)
        for name, value in expected.items():
            got = frame.at[i, name]
            if value is None:
                assert math.isnan(got), (i, name)
            else:
                defined += 1
                assert got == pytest.approx(value, rel=1e-12, abs=1e-15), (i, name)
    assert defined > 100
    assert list(frame["conflict_success"]) == [c.success for c in cons]


def test_evaluate_pairs_streams_generators_and_rejects_misaligned_inputs():
    rng = np.random.default_rng(5)
    refs = [_random_record(rng, None, h=10) for _ in range(5)]
    cons = [_random_record(rng, f"c{i}", h=12) for i in range(5)]
    whole = evaluate_pairs(refs, cons)
    streamed = evaluate_pairs(iter(refs), (c for c in cons), chunk_size=2)
    assert whole[["tar", "ts", "early20_ts", "ams"]].equals(streamed[["tar", "ts", "early20_ts", "ams"]])
    with pytest.raises(ValueError):
        evaluate_pairs(refs, cons[:4])
    assert len(evaluate_pairs([], [])) == 0


class StepRatio:
    """An in-process plugin: conflict steps over reference steps."""

    @hookimpl
    def conflictbench_register_metrics(self, register):
        register(
            "step_ratio",
            compute=lambda pair: pair.conflict.steps / pair.reference.steps if pair.reference.steps else None,
            description="conflict steps / reference steps",
        )


def test_builtins_are_registered_through_the_hook_and_plugins_join_pair_metrics():
    specs = conflictbench.plugins(entry_points=False).metrics()
    for name in ("tar", "ts", "early20_ts", "ams"):
        assert specs[name].plugin == "conflictbench" and specs[name].description
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[StepRatio()])
    ref = record(eef=line([0, 0.1]), case=None, steps=40)
    con = record(eef=line([0, 0.1]), steps=10)
    values = pair_metrics(ref, con, plugins=plugins)
    assert {"tar", "ts", "early20_ts", "ams"} <= set(values)
    assert values["step_ratio"] == 0.25
    assert values["ts"] == 1.0
    # the registered functions give the same values one Pair at a time
    assert specs["ts"].compute_pair(Pair(ref, con)) == 1.0
    assert pair_metrics(ref, record(eef=line([0, 0.1]), steps=10))["ts"] == 1.0  # default plugins


def test_a_failing_plugin_metric_is_undefined_with_a_warning():
    class Broken:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("broken", compute=lambda pair: 1 / 0)

    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[Broken()])
    with pytest.warns(UserWarning, match="broken"):
        values = pair_metrics(record(case=None), record(), plugins=plugins)
    assert values["broken"] is None and values["ts"] == 1.0
