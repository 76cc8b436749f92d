"""The report's intervals cover the truth, and its paired tests call differences only where they are real.

Simulated stores with a known truth (tests/crossed_effects.py: crossed random effects for base task, case and
initial state measured on a real store, references shared as the runner shares them) at the sizes of
``run=paper`` (every case of the shipped suite, 5 initial states: 8,670 pairs, 40 base tasks) and of the default
slice (one case per family and level: 4 pairs a family). The default selection runs a short version; the full one
(1,000 stores per configuration) is marked slow. Each prints the figures it measured.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from crossed_effects import MEASURES, Components, simulate, suite_layout, truth

from conflictbench.metrics.measures import intervals
from conflictbench.metrics.paired import differences

BATCH = 50  # stores simulated at once (about 430,000 pairs at the paper's size)
RATES = (0.05, 0.5, 0.95)


@pytest.fixture(scope="module")
def components() -> Components:
    return Components.from_measurements()


@pytest.fixture(scope="module")
def paper():
    return suite_layout(None, 5)


@pytest.fixture(scope="module")
def default():
    return suite_layout(1, 1)


def configurations(rate: float):
    """(rates of PCSR, RGSR and TS, the measures checked there): PCSR, RGSR, dSR and TS where PCSR = RGSR = TS =
    rate; FR where PCSR = 0.5 and RGSR = 1 - rate (FR near ``rate``: its truth, :func:`truth`, counts the
    generator's reference-conflict correlation)."""
    return [((rate, rate, rate), ("PCSR", "RGSR", "dSR", "ts")), ((0.5, 1 - rate, 0.5), ("FR",))]


def coverage(layout, stores, rates, names, comp, seed, pair_level=False) -> dict[str, float]:
    """Share of simulated stores whose 95 % interval holds the truth, per measure and row (overall, family);
    rows where the measure is undefined (FR without a successful reference) are not counted."""
    measures = [m for m in MEASURES if m.name in names]
    true = truth(*rates, comp)
    rng = np.random.default_rng(seed)
    held: dict[str, list[bool]] = {}
    for start in range(0, stores, BATCH):
        frame = simulate(layout, min(BATCH, stores - start), rng, comp, rates)
        if pair_level:  # clustering ignored: every pair a base task of its own
            frame = frame.assign(suite="s", task_id=np.arange(len(frame)))
        for row, by in (("overall", ("store",)), ("family", ("store", "family"))):
            table = intervals(frame, by, measures)
            for m in measures:
                value = getattr(true, m.name)
                defined = table[f"{m.name}_lo"].notna()
                inside = (table[f"{m.name}_lo"] <= value + 1e-12) & (value - 1e-12 <= table[f"{m.name}_hi"])
                held.setdefault(f"{row} {m.name}", []).extend(inside[defined].tolist())
    return {key: float(np.mean(values)) for key, values in held.items()}


def show(title: str, figures: dict[str, float]) -> None:
    print(f"\n{title}: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in figures.items()))


@pytest.mark.slow  # a coverage simulation of 5 s: CI's marked lane runs it
def test_intervals_cover_the_truth_at_the_papers_size_and_pair_level_ones_do_not(components, paper):
    clustered = coverage(paper, 200, (0.5, 0.5, 0.5), ("PCSR", "RGSR", "dSR", "ts"), components, seed=1)
    pair_level = coverage(paper, 100, (0.5, 0.5, 0.5), ("PCSR", "dSR", "ts"), components, seed=2, pair_level=True)
    show("clustered, 200 stores", clustered)
    show("pair-level, 100 stores", pair_level)
    assert all(0.91 <= v <= 0.99 for v in clustered.values()), clustered  # 95 % within the noise of 200 stores
    assert all(v < 0.8 for v in pair_level.values()), pair_level


@pytest.mark.slow
@pytest.mark.parametrize("rate", RATES)
def test_intervals_cover_the_truth_in_93_to_97_percent_of_paper_sized_stores(components, paper, rate):
    for rates, names in configurations(rate):
        figures = coverage(paper, 1000, rates, names, components, seed=int(100 * rate) + len(names))
        show(f"run=paper, rates {rates}, 1000 stores", figures)
        assert all(0.93 <= v <= 0.97 for v in figures.values()), figures


@pytest.mark.slow
@pytest.mark.parametrize("rate", RATES)
def test_intervals_cover_the_truth_in_at_least_93_percent_of_default_sized_stores(components, default, rate):
    for rates, names in configurations(rate):
        figures = coverage(default, 1000, rates, names, components, seed=7 + int(100 * rate) + len(names))
        show(f"default slice, rates {rates}, 1000 stores", figures)
        assert all(v >= 0.93 for v in figures.values()), figures


@pytest.mark.slow
def test_pair_level_intervals_undercover_at_the_papers_size(components, paper):
    figures = coverage(paper, 300, (0.5, 0.5, 0.5), ("PCSR", "RGSR", "dSR", "FR", "ts"), components, seed=3,
                       pair_level=True)  # fmt: skip
    show("pair-level (clustering ignored), run=paper, 300 stores", figures)
    assert all(v < 0.8 for v in figures.values()), figures


def called(layout, stores, rates_a, rates_b, comp, seed) -> pd.DataFrame:
    """Per simulated store, the overall row of the paired comparison A - B (two models sharing half of every
    random effect)."""
    rng = np.random.default_rng(seed)
    rows = []
    for start in range(0, stores, BATCH):
        frame = simulate(layout, min(BATCH, stores - start), rng, comp, rates_a, models=2, second_rates=rates_b)
        rows.append(differences(frame, ("store",), MEASURES))
    return pd.concat(rows, ignore_index=True)


def found(apart: pd.DataFrame) -> tuple[float, float]:
    """How often the overall row calls A's higher dSR (this report's test), and how often a test that knew the
    estimate's true spread would (its standard deviation over the simulated stores: the most any test can)."""
    ours = float(((apart["dSR_p"] < 0.05) & (apart["dSR"] > 0)).mean())
    oracle = float((apart["dSR"] / apart["dSR"].std() > 1.96).mean())
    return ours, oracle


def check_comparisons(stores: int, fpr_limit: float, seeds: tuple[int, int, int], components, paper, slack=0.0):
    alike = called(paper, stores, (0.6, 0.3, 0.5), (0.6, 0.3, 0.5), components, seed=seeds[0])
    false_positives = {m.name: float((alike[f"{m.name}_p"] < 0.05).mean()) for m in MEASURES}
    show(f"two models alike, run=paper, {stores} stores: overall row called different", false_positives)
    assert all(v <= fpr_limit for v in false_positives.values()), false_positives
    # A's dSR 15 and 20 points above B's (RGSR 30 % against 45 % or 50 %, PCSR 60 % both)
    for difference, seed in ((0.15, seeds[1]), (0.20, seeds[2])):
        ours, oracle = found(called(paper, stores, (0.6, 0.3, 0.5), (0.6, 0.3 + difference, 0.5), components, seed))
        print(f"a {100 * difference:.0f}-point dSR difference, {stores} stores: found in {100 * ours:.1f} % "
              f"(a test knowing the true spread: {100 * oracle:.1f} %)")  # fmt: skip
        # in this generator even a test knowing the true spread finds 15 points in about 80 % (PCSR's task-level
        # noise): ours keeps close to the most any can; at 20 points it finds it in over 80 %
        assert ours >= 0.85 * oracle - slack
        if difference == 0.20:
            assert ours >= 0.8 - slack


@pytest.mark.slow  # a coverage simulation of 5 s: CI's marked lane runs it
def test_two_models_alike_are_seldom_told_apart_and_a_dsr_difference_is_found(components, paper):
    check_comparisons(100, 0.12, (4, 5, 9), components, paper, slack=0.1)  # 100 stores: within their noise


@pytest.mark.slow
def test_false_positives_at_most_6_5_percent_and_dsr_differences_found_near_the_most_possible(components, paper):
    check_comparisons(1000, 0.065, (6, 8, 10), components, paper)
