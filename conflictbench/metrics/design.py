"""How wide can a slice's intervals be? The plan line's bound on dSR per family, and README's power table.

A slice plays, per base task t of a family, c_t cases crossed with s_t initial states: n = sum c_t s_t pairs
in G base tasks. Pairs of one task are correlated: r_case between two pairs of one case (other initial states),
r_state between two pairs of one initial state (other cases, one shared reference) and r_task between two
pairs sharing only the task (measured on the learned subject, ``correlations.json``, written by
``scripts/measure_correlations.py``). Their variance is the independent pairs' times the design effect

    deff = 1 + sum_t c_t s_t [(s_t - 1) r_case + (c_t - 1) r_state + (c_t - 1)(s_t - 1) r_task] / n,

so the pairs count as n_eff = n / deff (at most n - 1). At worst a pair's dSR (y+ - y-, in {-1, 0, 1}) has
variance 1, the variance a score interval assumes at dSR = 0, and the 95 % interval of :mod:`.intervals` is then
at most

    +-2 q sqrt(n_eff / 4 + q^2 / 4) / (n_eff + q^2)    (q: Student's t, 97.5 %),

a half-width at dSR = 0 (elsewhere the interval is asymmetric and narrower in all), with the degrees of freedom the
report's count gives G alike base tasks (about G / 3, at least 5, at most G - 1); the whole range with fewer than
two base tasks. "About": it holds where the correlations are the measured ones; where a few tasks carry the
variance, or tasks differ more than measured, the report's degrees of freedom are fewer and its interval wider.
The slice's intra-cluster correlation, printed beside it, is (deff - 1) / (m - 1), m the pairs' mean task size as
the pairs see it (sum n_t^2 / n).
"""

from __future__ import annotations

import functools
import json
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from importlib import resources

from scipy import special

from conflictbench.core.words import counted

from .intervals import DF_FLOOR

CORRELATIONS_FILE = "correlations.json"


@functools.cache
def correlations() -> dict:
    """The measured correlations (``correlations.json``: values, the command and store they come from)."""
    with (resources.files("conflictbench.metrics") / CORRELATIONS_FILE).open(encoding="utf-8") as f:
        return json.load(f)


def dsr_correlations() -> tuple[float, float, float]:
    """(r_task, r_case, r_state) of a pair's dSR, never below 0 (a negative estimate is noise here)."""
    measured = correlations()["dSR"]
    return tuple(max(0.0, float(measured[k])) for k in ("task", "case", "state"))


@dataclass(frozen=True)
class Design:
    pairs: int
    clusters: int
    deff: float
    icc: float
    """The intra-cluster correlation the design effect amounts to for this slice."""

    @property
    def effective(self) -> float:
        """n / deff, and at most n - 1 (the independent pairs' variance counts n / (n - 1) of theirs)."""
        return min(self.pairs / self.deff, self.pairs - 1) if self.deff > 0 and self.pairs > 1 else 0.0


def design(layout: Iterable[tuple[int, int]], corr: tuple[float, float, float] | None = None) -> Design:
    """``layout``: (cases, initial states) per base task, played crossed."""
    r_task, r_case, r_state = corr or dsr_correlations()
    n = extra = square = 0.0
    tasks = 0
    for c, s in layout:
        if c <= 0 or s <= 0:
            continue
        tasks += 1
        n += c * s
        square += (c * s) ** 2
        extra += c * s * ((s - 1) * r_case + (c - 1) * r_state + (c - 1) * (s - 1) * r_task)
    if n == 0:
        return Design(0, 0, 1.0, 0.0)
    deff = 1 + extra / n
    m = square / n
    return Design(int(n), tasks, deff, (deff - 1) / (m - 1) if m > 1 else 0.0)


def usual_df(clusters: int) -> float:
    """The degrees of freedom the report's intervals take for G alike base tasks: its count
    (:func:`~conflictbench.metrics.intervals.degrees_of_freedom`) comes to about G / 3 there, at least
    :data:`~conflictbench.metrics.intervals.DF_FLOOR`, at most G - 1."""
    return float(min(clusters - 1, max(DF_FLOOR, clusters / 3)))


def worst_half_width(d: Design, level: float = 0.95, df: float | None = None) -> float:
    """The widest half-width of a 95 % interval on dSR (a fraction; 1 = the whole range) this design gives at dSR
    = 0, with ``df`` degrees of freedom (default: :func:`usual_df`)."""
    if d.clusters < 2 or d.pairs == 0:
        return 1.0
    q = float(special.stdtrit(usual_df(d.clusters) if df is None else df, 0.5 + level / 2))
    n_eff = d.effective
    return min(1.0, 2 * q * math.sqrt(n_eff / 4 + q**2 / 4) / (n_eff + q**2))


def family_layouts(plan: Iterable) -> dict[str, list[tuple[int, int]]]:
    """(cases, initial states) per base task for each family of a plan's conflict episodes (one prompt
    condition's: rows of the tables are per prompt, and every prompt plays the same)."""
    cases: dict[str, dict] = defaultdict(lambda: defaultdict(set))
    states: dict[str, dict] = defaultdict(lambda: defaultdict(set))
    prompts = sorted({e.prompt for e in plan if getattr(e, "case", None) is not None})
    for episode in plan:
        if episode.case is None or episode.prompt != prompts[0]:
            continue
        task = (episode.suite, episode.task_id)
        cases[episode.case.family][task].add(episode.case.case_id)
        states[episode.case.family][task].add(episode.init_state)
    return {f: [(len(cases[f][t]), len(states[f][t])) for t in cases[f]] for f in cases}


def plan_line(plan: Iterable, families: Iterable[str]) -> str | None:
    """The plan's bound on dSR per family, e.g. ``dSR per family: 95 % intervals of about +-18 pp at most (widest:
    physical, 2,135 pairs in 40 base tasks; intra-cluster correlation 0.22 assumed, ...)``."""
    layouts = family_layouts(list(plan))
    shown = [f for f in families if f in layouts]
    if not shown:
        return None
    designs = {f: design(layouts[f]) for f in shown}
    widths = {f: worst_half_width(d) for f, d in designs.items()}
    widest = max(shown, key=lambda f: widths[f])
    d = designs[widest]
    half = "the whole range (fewer than two base tasks)" if widths[widest] >= 1 else f"+-{100 * widths[widest]:.0f} pp"
    correlation = (
        "one pair a base task, so no correlation within one enters"
        if d.pairs <= d.clusters
        else f"intra-cluster correlation {d.icc:.2f} assumed, measured on the learned subject"
    )
    return (
        f"dSR per family: 95 % intervals of about {half} at most (widest: {widest}, {counted(d.pairs, 'pair')} in "
        f'{d.clusters} base tasks; {correlation}: README, "Uncertainty")'
    )


def power(d: Design, difference: float, variance: float, alpha: float = 0.05) -> float:
    """The chance that a paired test at ``alpha`` tells apart a true ``difference`` whose per-pair variance is
    ``variance``, with this design (normal approximation around Student's t at :func:`usual_df`)."""
    if d.clusters < 2 or d.pairs == 0:
        return 0.0
    q = float(special.stdtrit(usual_df(d.clusters), 1 - alpha / 2))
    se = math.sqrt(variance / d.effective)
    return float(special.ndtr(abs(difference) / se - q))


def states_needed(
    per_task_cases: Mapping[object, int],
    difference: float,
    variance: float,
    corr: tuple[float, float, float] | None = None,
    alpha: float = 0.05,
    target: float = 0.8,
    most: int = 50,
) -> int | None:
    """The fewest initial states (of LIBERO's 50) for which two models' paired comparison reaches ``target``
    power on ``difference`` (None: not within ``most``), every case of each task played."""
    for states in range(1, most + 1):
        d = design(((c, states) for c in per_task_cases.values()), corr)
        if power(d, difference, variance, alpha) >= target:
            return states
    return None
