"""The report's intervals and paired tests, pinned on small frames worked by hand (README, "Uncertainty")."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from conflictbench.core import PluginError
from conflictbench.metrics.intervals import DF_FLOOR, holm
from conflictbench.metrics.measures import DSR, PCSR, RGSR, intervals, metric_measure
from conflictbench.metrics.paired import differences


def pairs(reference, conflict, tasks=None, **columns) -> pd.DataFrame:
    """One row per pair: its outcomes and base task (each pair its own task unless given)."""
    n = len(reference)
    return pd.DataFrame(
        {
            "suite": "libero_goal",
            "task_id": list(range(n)) if tasks is None else tasks,
            "reference_success": np.asarray(reference, dtype=bool),
            "conflict_success": np.asarray(conflict, dtype=bool),
            **columns,
        }
    )


def wilson(u: float, n: float, q: float) -> tuple[float, float]:
    centre = (u + q**2 / (2 * n)) / (1 + q**2 / n)
    half = q / (1 + q**2 / n) * math.sqrt(u * (1 - u) / n + q**2 / (4 * n**2))
    return centre - half, centre + half


def one(frame: pd.DataFrame, measure) -> pd.Series:
    return intervals(frame, (), [measure]).iloc[0]


def test_independent_pairs_get_wilsons_interval_with_n_minus_1_and_satterthwaites_t():
    # 3 of 10 references succeeded, each pair a base task of its own. Influences (x - 0.3) / 10: three of 0.07
    # and seven of -0.03. Variance: the independent pairs' 10/9 * sum e^2 = 0.21 / 9 (above the clustered
    # sum e^2 = 0.021), so n_eff = 0.21 / (0.21 / 9) = 9; Satterthwaite: 0.021^2 / (3 * 0.07^4 + 7 * 0.03^4) = 5.68
    row = one(pairs([1] * 3 + [0] * 7, [0] * 10), PCSR)
    df = 0.021**2 / (3 * 0.07**4 + 7 * 0.03**4)
    assert df == pytest.approx(5.676, abs=1e-3) and df > DF_FLOOR
    low, high = wilson(0.3, 9, stats.t.ppf(0.975, df))
    assert (row["PCSR"], row["PCSR_clusters"]) == (0.3, 10)
    assert row["PCSR_lo"] == pytest.approx(low, abs=1e-12) and row["PCSR_hi"] == pytest.approx(high, abs=1e-12)


@pytest.mark.parametrize("succeeded", [0, 4])
def test_zero_of_n_and_n_of_n_get_wilsons_bound_over_base_tasks_not_a_point(succeeded):
    # 4 pairs in 4 base tasks, all alike: w = t(3)^2 / (4 + t(3)^2) = 0.7169; 4/4 -> [0.2831, 1], 0/4 -> [0, 0.7169]
    row = one(pairs([succeeded > 0] * 4, [0] * 4), PCSR)
    w = stats.t.ppf(0.975, 3) ** 2 / (4 + stats.t.ppf(0.975, 3) ** 2)
    assert w == pytest.approx(0.7169, abs=1e-4)
    expected = (1 - w, 1.0) if succeeded else (0.0, w)
    assert (row["PCSR_lo"], row["PCSR_hi"]) == pytest.approx(expected, abs=1e-12)


def test_all_alike_counts_base_tasks_not_pairs():
    # 40 pairs in 4 base tasks, all succeeded: the bound is Wilson's for 4 of 4, not 40 of 40
    row = one(pairs([1] * 40, [0] * 40, tasks=[i // 10 for i in range(40)]), PCSR)
    q = stats.t.ppf(0.975, 3)
    assert row["PCSR_lo"] == pytest.approx(1 - q**2 / (4 + q**2))


def test_one_base_task_gives_the_whole_range():
    row = one(pairs([1, 0, 1], [0, 0, 1], tasks=[5, 5, 5]), DSR)
    assert (row["dSR"], row["dSR_lo"], row["dSR_hi"], row["dSR_clusters"]) == pytest.approx((1 / 3, -1, 1, 1))


def test_pairs_sharing_a_base_task_count_as_fewer_than_independent_ones():
    rng = np.random.default_rng(3)
    task_success = rng.random(12) < 0.5
    reference = np.repeat(task_success, 5)  # the references of one task succeed or fail together
    clustered = one(pairs(reference, np.zeros(60), tasks=np.repeat(np.arange(12), 5)), PCSR)
    independent = one(pairs(reference, np.zeros(60)), PCSR)
    assert clustered["PCSR"] == independent["PCSR"]
    width = clustered["PCSR_hi"] - clustered["PCSR_lo"]
    assert width > 1.8 * (independent["PCSR_hi"] - independent["PCSR_lo"])


def test_a_signed_sum_combines_its_ratios_intervals():
    # 6 pairs in 6 tasks, every reference succeeded, 2 conflicts did too: PCSR's interval is Wilson's bound
    # [1 - w, 1], RGSR's its score interval [l, h]; PCSR does not vary, so the two are uncorrelated and dSR = 2/3
    # has low = 2/3 - sqrt(w^2 + (h - 1/3)^2), high = 2/3 + sqrt(0 + (1/3 - l)^2)
    frame = pairs([1] * 6, [1, 0, 0, 0, 1, 0])
    rgsr = one(frame, RGSR)
    low, high = rgsr["RGSR_lo"], rgsr["RGSR_hi"]
    q = stats.t.ppf(0.975, 5)
    w = q**2 / (6 + q**2)
    row = one(frame, DSR)
    expected = (2 / 3 - math.sqrt(w**2 + (high - 1 / 3) ** 2), 2 / 3 + (1 / 3 - low))
    assert (row["dSR"], row["dSR_lo"], row["dSR_hi"]) == pytest.approx((2 / 3, *expected))


def test_a_sum_whose_pairs_all_agree_keeps_its_own_bound():
    # 4 pairs in 4 tasks, every reference succeeded and no conflict did: dSR = 1 in every pair, so dSR keeps
    # Wilson's bound for none of 4 base tasks differing on its range [-1, 1] (wider than its ratios' combination)
    row = one(pairs([1] * 4, [0] * 4), DSR)
    w = stats.t.ppf(0.975, 3) ** 2 / (4 + stats.t.ppf(0.975, 3) ** 2)
    assert (row["dSR"], row["dSR_lo"], row["dSR_hi"]) == pytest.approx((1.0, 1 - 2 * w, 1.0))


def test_the_same_frame_in_another_order_gives_the_same_intervals():
    rng = np.random.default_rng(5)
    frame = pairs(rng.random(200) < 0.6, rng.random(200) < 0.3, tasks=rng.integers(0, 30, 200), ts=rng.random(200))
    frame["family"] = rng.choice(["instruction", "spatial"], 200)
    measures = [PCSR, RGSR, DSR, metric_measure("ts", (0.0, 1.0))]
    one_way = intervals(frame, ("family",), measures).sort_values("family").reset_index(drop=True)
    shuffled = frame.sample(frac=1, random_state=1).reset_index(drop=True)
    other_way = intervals(shuffled, ("family",), measures).sort_values("family").reset_index(drop=True)
    pd.testing.assert_frame_equal(one_way, other_way, check_exact=False, rtol=1e-12, atol=1e-15)


def test_a_metric_without_a_range_gets_a_t_interval_and_none_where_its_pairs_all_agree():
    frame = pairs([1] * 6, [0] * 6, metres=[0.1, 0.3, 0.2, 0.4, 0.2, 0.3])
    row = one(frame, metric_measure("metres", None))
    values = np.array([0.1, 0.3, 0.2, 0.4, 0.2, 0.3])
    half = stats.t.ppf(0.975, 5) * math.sqrt(values.var(ddof=1) / 6)  # the independent pairs' variance wins
    assert (row["metres_lo"], row["metres_hi"]) == pytest.approx((values.mean() - half, values.mean() + half))
    flat = one(pairs([1] * 6, [0] * 6, metres=[0.2] * 6), metric_measure("metres", None))
    assert flat["metres"] == pytest.approx(0.2) and np.isnan(flat["metres_lo"]) and np.isnan(flat["metres_hi"])


def test_a_p_value_agrees_with_the_interval():
    rng = np.random.default_rng(11)
    for trial in range(20):
        n = 40
        frame = pd.DataFrame(
            {
                "suite": "s",
                "task_id": rng.integers(0, 15, n),
                "family": "f",
                "reference_success_a": rng.random(n) < 0.7,
                "conflict_success_a": rng.random(n) < 0.2 + 0.02 * trial,
                "reference_success_b": rng.random(n) < 0.7,
                "conflict_success_b": rng.random(n) < 0.4,
            }
        )
        row = differences(frame, (), [RGSR, DSR]).iloc[0]
        for name in ("RGSR", "dSR"):
            outside = not (row[f"{name}_lo"] <= 0 <= row[f"{name}_hi"])
            assert outside == (row[f"{name}_p"] < 0.05), (trial, name, row[f"{name}_p"])


def test_holm_multiplies_the_smallest_p_by_the_number_of_tests_and_keeps_the_order():
    assert holm([0.01, 0.04, 0.03, np.nan]) == pytest.approx([0.03, 0.06, 0.06, np.nan], nan_ok=True)
    assert holm([0.5, 0.6]) == pytest.approx([1.0, 1.0])


def test_a_registered_range_is_checked_and_a_percent_metric_is_in_0_1(tmp_path):
    import conflictbench
    from conflictbench.core import Plugins, hookimpl

    class Ranged:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("gap", compute=lambda pair: 0.0, unit="cm", bounds=(0, 50))

    class Wrong:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("gap", compute=lambda pair: 0.0, bounds=(1, 1))

    metrics = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[Ranged()]).metrics()
    assert metrics["gap"].bounds == (0.0, 50.0) and metrics["ts"].bounds == (0.0, 1.0)
    with pytest.raises(PluginError, match="bounds must be finite with low < high"):
        Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[Wrong()]).metrics()


def test_concordant_pairs_keep_a_bound_on_their_dsr():
    # every pair's reference and conflict agree (dSR 0 in each): PCSR and RGSR move together and their MOVER limits
    # cancel; the sum keeps Wilson's bound for none of 6 base tasks differing, on dSR's range [-1, 1]
    outcomes = [1, 0, 1, 1, 0, 0]
    row = one(pairs(outcomes, outcomes), DSR)
    q = stats.t.ppf(0.975, 5)
    w = q**2 / (6 + q**2)
    assert row["dSR"] == 0 and (row["dSR_lo"], row["dSR_hi"]) == pytest.approx((-w, w))


def test_a_paired_difference_of_models_that_mostly_agree_is_about_as_wide_as_a_plain_clustered_t_interval():
    # 40 base tasks x 5 pairs; B differs from A on 6 % of the pairs. The paired difference's interval is that of
    # its own variance: no worst case of two sides disagreeing everywhere widens it (against a cluster-robust t
    # interval of the per-pair differences, computed here from its textbook formula)
    rng = np.random.default_rng(2)
    n = 200
    tasks = np.repeat(np.arange(40), 5)
    a = rng.random(n) < 0.4
    b = np.where(rng.random(n) < 0.06, ~a, a)
    frame = pd.DataFrame({"suite": "s", "task_id": tasks, "reference_success_a": True, "reference_success_b": True,
                          "conflict_success_a": a, "conflict_success_b": b})  # fmt: skip
    row = differences(frame, (), [RGSR]).iloc[0]
    d = a.astype(float) - b.astype(float)
    sums = pd.Series(d - d.mean()).groupby(tasks).sum().to_numpy()
    t_half = stats.t.ppf(0.975, 39) * math.sqrt(40 / 39 * (sums**2).sum()) / n
    width = row["RGSR_hi"] - row["RGSR_lo"]
    assert row["RGSR"] == pytest.approx(d.mean()) and 0.8 < width / (2 * t_half) < 1.5


def test_a_metric_without_a_range_whose_sides_always_differ_alike_gets_no_test():
    frame = pd.DataFrame({"suite": "s", "task_id": range(8), "metres_a": 1.01, "metres_b": 1.0,
                          "reference_success_a": True, "reference_success_b": True,
                          "conflict_success_a": False, "conflict_success_b": False})  # fmt: skip
    row = differences(frame, (), [metric_measure("metres", None)]).iloc[0]
    assert row["metres"] == pytest.approx(0.01)
    assert np.isnan(row["metres_lo"]) and np.isnan(row["metres_p"])


def test_a_value_outside_a_metrics_range_stops_the_report_in_one_line():
    from conflictbench.metrics import aggregate

    frame = pairs([1, 1, 0], [0, 1, 0], ts=[0.5, -0.3, 0.2])
    frame["model"], frame["prompt"] = "m", "p0"
    with pytest.raises(PluginError, match=r"metric 'ts' gave 1 value\(s\) outside its range \[0, 1\] \(e.g. -0.3\)"):
        aggregate(frame, ("model",), ["ts"], {"ts": (0.0, 1.0)})
