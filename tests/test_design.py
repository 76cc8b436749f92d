"""The plan line's bound on dSR per family (conflictbench/metrics/design.py), against its definition and the
report's own intervals."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from conflictbench.core import FAMILIES, LEVELS
from conflictbench.metrics.design import design, dsr_correlations, plan_line, states_needed, worst_half_width
from conflictbench.metrics.measures import DSR, intervals
from conflictbench.sim.plan import build_plan
from conflictbench.tasks.suite.file import load_suite


def test_the_design_effect_is_the_mean_pairwise_correlation_it_assumes():
    corr = (0.1, 0.5, 0.3)  # task only, same case, same initial state
    layout = [(2, 3), (4, 1), (1, 5)]
    # every pair of pairs of one task, by what they share: the variance of the mean of n unit-variance pairs
    # is (n + sum of their correlations) / n^2
    total, n = 0.0, 0
    for cases, states in layout:
        cells = list(itertools.product(range(cases), range(states)))
        n += len(cells)
        for (c1, s1), (c2, s2) in itertools.permutations(cells, 2):
            total += corr[1] if c1 == c2 else corr[2] if s1 == s2 else corr[0]
    d = design(layout, corr)
    assert (d.pairs, d.clusters) == (n, 3)
    assert d.deff == pytest.approx(1 + total / n)
    sizes = np.array([6, 4, 5])
    assert d.icc == pytest.approx((d.deff - 1) / ((sizes**2).sum() / n - 1))


def test_the_worst_half_width_is_the_reports_own_interval_at_the_worst_case_and_its_degrees_of_freedom():
    # 12 pairs in 12 base tasks: half with y+ = 1, y- = 0 and half the other way round: dSR 0 at the most
    # variance a pair's dSR can have; the report's interval is then exactly the bound
    n = 12
    frame = pd.DataFrame(
        {
            "suite": "s",
            "task_id": range(n),
            "reference_success": [True, False] * (n // 2),
            "conflict_success": [False, True] * (n // 2),
        }
    )
    row = intervals(frame, (), [DSR]).iloc[0]
    # alike tasks of exactly equal influence: the report's degrees of freedom are G - 1 here, and its interval
    # is the bound at G - 1; at the degrees of freedom alike tasks usually give (about G / 3), the bound is wider
    exact = worst_half_width(design([(1, 1)] * n), df=n - 1)
    assert row["dSR"] == 0 and row["dSR_hi"] == pytest.approx(exact) and row["dSR_lo"] == pytest.approx(-exact)
    assert worst_half_width(design([(1, 1)] * n)) > exact
    assert worst_half_width(design([(3, 1)])) == 1.0  # one base task: the whole range


def plan(cases_per_cell, states):
    suite = load_suite(None)
    tasks = {(c.suite, c.task_id): c.base_instruction for c in suite.cases}
    return build_plan(suite.cases, base_instructions=tasks, families=FAMILIES, levels=LEVELS, prompts=("p0", "p1"),
                      init_states=list(range(states)), cases_per_cell=cases_per_cell)  # fmt: skip


def test_the_plan_line_of_the_default_slice_and_of_the_papers_protocol():
    default = plan_line(plan(1, 1), FAMILIES)
    assert default.startswith("dSR per family: 95 % intervals of about +-")
    assert "4 pairs in 4 base tasks; one pair a base task, so no correlation within one enters" in default
    paper = plan_line(plan(None, 5), FAMILIES)
    half = int(paper.split("+-")[1].split(" pp")[0])
    assert 5 < half < 30 and "in 40 base tasks; intra-cluster correlation 0." in paper
    assert 'README, "Uncertainty"' in paper
    only = plan_line([e for e in plan(1, 1) if e.case is None or e.case.family == "spatial"], ["spatial"])
    assert "widest: spatial" in only


def test_more_initial_states_are_needed_for_a_smaller_difference():
    cases = {task: 10 for task in range(40)}
    assert dsr_correlations() == tuple(max(0.0, r) for r in dsr_correlations())
    few = states_needed(cases, 0.2, 0.6)
    many = states_needed(cases, 0.1, 0.6)
    assert few is not None and (many is None or many > few)
