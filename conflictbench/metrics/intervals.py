"""95 % intervals and paired tests over pairs that share references and scenes (README, "Uncertainty").

Every measure of the report is a ratio of sums over pairs: PCSR = sum(y+) / pairs, FR = sum(qualified
failure) / sum(y+), a process measure = sum(value) / (pairs where defined); dSR and a paired difference
between two models or two prompts are signed sums of such ratios. A :class:`Term` is one ratio (a numerator
and a weight per pair), a :class:`Measure` a signed sum of terms.

Pairs are not independent: a reference episode is shared by every case of its (task, initial state,
prompt), and a case by every initial state it is played from. Within one base task every pair is linked
to every other through these two, so the base task is the smallest cluster between which pairs are
independent. A ratio's variance is the cluster-robust one of its linearisation (the pairs' influences summed
per base task, their sum of squares: CR0), never below the variance the pairs would give if they were
independent. Student's t takes an effective number of degrees of freedom from how evenly the base tasks carry
that variance, (sum E_g^2)^2 / sum E_g^4 (a Satterthwaite-type count with the observed sums: about G / 3 for G
alike base tasks, fewer where a few carry it, as with a rare event), at least :data:`DF_FLOOR`, at most G - 1.

A ratio's interval is a score (Wilson) interval on the measure's range with the effective number of pairs that
variance implies (Korn & Graubard's design-effect Wilson interval: u (1 - u) / variance on the range scaled to
[0, 1]), so it stays inside the range. For one side's ratio of a bounded measure, a variance below the most its
pairs could vary if independent (u (1 - u) / n, Bhatia-Davis on the declared range) is raised towards it as by one
degree of freedom: a few base tasks of a skewed measure understate its spread. Two cases have no variance to work with:
- every pair gives the same value c (0/n, n/n): the chance that a pair of the population differs from c is at
  most w = q^2 / (G + q^2) (Wilson's bound for none of G base tasks differing), so the interval is
  [c - w (c - low), c + w (high - c)]: for a rate, Wilson's interval of 0 of G;
- fewer than two base tasks: nothing measures how base tasks differ, so the interval is the whole range.
A signed sum of several ratios (dSR, and a paired difference of dSR, whose pieces are each ratio's difference
between the sides) combines its pieces' intervals with their correlation (MOVER, Zou and Donner), so a ratio at
0/n brings its own non-degenerate bound; a paired difference of one ratio gets the score interval of its own
variance on its range. A measure without a declared range (a plugin
metric whose unit is not "%") gets the t interval of the same variance, and no interval in those two cases.
A p-value is one minus the lowest level whose interval holds the null, so it agrees with the interval.

Everything here is closed-form: the same frame gives the same intervals, whatever its row order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import special

LEVEL = 0.95
#: What a cluster is: the base task (README, "Uncertainty" says why).
CLUSTER_KEYS = ("suite", "task_id")
#: A deviation this small, relative to the measure's range, is no deviation (rounding in the ratios).
_FLAT = 1e-9
#: The degrees of freedom are not taken below this (where fewer base tasks do not cap them first): with one or
#: two base tasks carrying the variance the count gives 1 or 2, an interval several times too wide (README,
#: "Uncertainty": in the coverage simulation, 99 % at rates of 5 and 95 % without the floor).
DF_FLOOR = 5
#: Degrees of freedom the worst case's variance counts for where the estimate is below it (ratio_interval).
WORST_CASE_WEIGHT = 1.0

Bounds = tuple[float, float] | None


@dataclass(frozen=True)
class Term:
    """One ratio: ``numerator(frame, suffix) / weight(frame, suffix)``, summed over the pairs, in ``bounds``."""

    numerator: Callable[[pd.DataFrame, str], np.ndarray]
    weight: Callable[[pd.DataFrame, str], np.ndarray]
    bounds: Bounds


@dataclass(frozen=True)
class Measure:
    """A signed sum of ratios (``terms``: (sign, term) on one side, or (sign, term, side) with side 0 or 1 for a
    paired difference); its range is the sum of theirs."""

    name: str
    terms: tuple[tuple, ...]

    @property
    def bounds(self) -> Bounds:
        return combined_bounds(self.terms)

    def minus(self) -> Measure:
        """This measure of side A minus the same of side B (the columns of ``suffixes[0]`` and ``[1]``)."""
        return Measure(self.name, (*((s, t, 0) for s, t, *_ in self.terms), *((-s, t, 1) for s, t, *_ in self.terms)))


def combined_bounds(terms: Sequence[tuple]) -> Bounds:
    low = high = 0.0
    for sign, term, *_ in terms:
        if term.bounds is None:
            return None
        a, b = term.bounds
        low, high = (low + a, high + b) if sign > 0 else (low - b, high - a)
    return (low, high)


@dataclass
class Estimates:
    """Per group: the value, its variance, how many pairs and base tasks carry it, and whether every pair
    says the same (no deviation from the value at all); ``cells``: the influences summed per (group, task)."""

    value: np.ndarray
    variance: np.ndarray
    cluster_variance: np.ndarray
    units: np.ndarray
    clusters: np.ndarray
    flat: np.ndarray
    bounds: Bounds
    cells: np.ndarray
    cell_group: np.ndarray


@dataclass(frozen=True)
class Grouping:
    """Rows' groups and base tasks, and the (group, task) cells they fall in, computed once per frame."""

    group: np.ndarray
    n_groups: int
    cluster: np.ndarray
    cell_index: np.ndarray
    cell_group: np.ndarray

    @classmethod
    def of(cls, group: np.ndarray, n_groups: int, cluster: np.ndarray) -> Grouping:
        width = int(cluster.max(initial=0)) + 1
        cells, index = np.unique(group.astype(np.int64) * width + cluster, return_inverse=True)
        return cls(group, n_groups, cluster, index, cells // width)

    def clusters(self) -> np.ndarray:
        """How many base tasks each group's rows come from."""
        return np.bincount(self.cell_group, minlength=self.n_groups)

    def per_group(self, values: np.ndarray) -> np.ndarray:
        return np.bincount(self.cell_group, values, minlength=self.n_groups)


def estimate(
    frame: pd.DataFrame,
    measure: Measure,
    group: np.ndarray | Grouping,
    n_groups: int | None = None,
    cluster: np.ndarray | None = None,
    suffixes: Sequence[str] = ("",),
) -> Estimates:
    """The measure per group of ``frame`` (``group``: each row's group, 0..n_groups-1; ``cluster``: its base
    task as an int; or a :class:`Grouping` of both). A term of side k reads the columns suffixed ``suffixes[k]``
    (a paired difference: two)."""
    grouping = group if isinstance(group, Grouping) else Grouping.of(group, n_groups, cluster)
    group, n_groups = grouping.group, grouping.n_groups
    influence = np.zeros(len(frame))
    value = np.zeros(n_groups)
    active = np.zeros(len(frame), dtype=bool)
    undefined = np.zeros(n_groups, dtype=bool)
    scale = np.zeros(n_groups)
    leveraged = np.zeros(len(grouping.cell_group))
    for sign, term, *side in measure.terms:
        suffix = suffixes[side[0] if side else 0]
        weight = np.asarray(term.weight(frame, suffix), dtype=np.float64)
        numerator = np.asarray(term.numerator(frame, suffix), dtype=np.float64)
        total = np.bincount(group, weight, minlength=n_groups)
        ratio = np.divide(np.bincount(group, numerator, minlength=n_groups), total, where=total > 0,
                          out=np.full(n_groups, np.nan))  # fmt: skip
        undefined |= total <= 0
        value += sign * ratio
        residual = numerator - np.nan_to_num(ratio)[group] * weight
        term_influence = np.divide(residual, total[group], where=total[group] > 0, out=np.zeros(len(frame)))
        influence += sign * term_influence
        cell_term = np.bincount(grouping.cell_index, term_influence, minlength=len(grouping.cell_group))
        leveraged += sign * cell_term
        active |= weight > 0
        scale = np.maximum(scale, np.nan_to_num(total))
    value[undefined] = np.nan
    units = np.bincount(group, active, minlength=n_groups)
    # pairs as if independent: n / (n - 1) * sum of squared influences
    pair_sum = np.bincount(group, influence**2, minlength=n_groups)
    pair_var = np.divide(units * pair_sum, units - 1, where=units > 1, out=np.zeros(n_groups))
    # base tasks: the influences summed per (group, task), their sum of squares (CR0; the degrees of freedom
    # carry the small-sample correction)
    cells = leveraged
    cell_active = np.bincount(grouping.cell_index, active, minlength=len(grouping.cell_group)) > 0
    clusters = grouping.per_group(cell_active).round().astype(np.int64)
    cluster_sum = grouping.per_group(cells**2)
    cluster_var = np.where(clusters > 1, cluster_sum, 0.0)
    # flat: no pair deviates (|influence| * the weight total is the pair's deviation from the ratio)
    deviation = np.zeros(n_groups)
    np.maximum.at(deviation, group, np.abs(influence) * scale[group])
    bounds = measure.bounds
    width = (bounds[1] - bounds[0]) if bounds else 1.0
    flat = deviation <= _FLAT * width
    variance = np.where(flat, 0.0, np.maximum(cluster_var, pair_var))
    return Estimates(value, variance, cluster_var, units.astype(np.int64), clusters, flat, bounds, cells,
                     grouping.cell_group)  # fmt: skip


def t_quantile(df: np.ndarray, level: float | np.ndarray = LEVEL) -> np.ndarray:
    """Student's t quantile for a two-sided ``level`` interval with ``df`` degrees of freedom (NaN below 1)."""
    df = np.asarray(df, dtype=np.float64)
    return np.where(df >= 1, special.stdtrit(np.maximum(df, 1), 0.5 + np.asarray(level) / 2), np.nan)


def degrees_of_freedom(est: Estimates) -> np.ndarray:
    """(sum_g E_g^2)^2 / sum_g E_g^4 over the base tasks' influences E_g: about G / 3 where they are alike, fewer
    where a few tasks carry the variance (a rare event); at least :data:`DF_FLOOR`, at most G - 1, and G - 1
    where nothing varies (the flat rule: what is left of the sums is rounding)."""
    second = np.bincount(est.cell_group, est.cells**2, minlength=len(est.value))
    fourth = np.bincount(est.cell_group, est.cells**4, minlength=len(est.value))
    most = np.maximum(est.clusters - 1, 1).astype(np.float64)
    concentration = np.divide(second**2, fourth, where=fourth > 0, out=most.copy())
    return np.where(est.flat, most, np.clip(np.maximum(concentration, DF_FLOOR), 1, most))


def ratio_interval(
    est: Estimates, level: float | np.ndarray = LEVEL, worst_case: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of one ratio per group: the score interval on its range (module docstring); ``worst_case``:
    raise a variance below the independent pairs' worst case towards it (one side's ratio, not a paired
    difference, whose worst case, two sides disagreeing on every pair, is far from any real one)."""
    value = est.value
    df = degrees_of_freedom(est)
    q = t_quantile(df, level)
    few = est.clusters < 2
    with np.errstate(invalid="ignore", divide="ignore"):
        if est.bounds is None:
            half = q * np.sqrt(est.variance)
            ok = ~few & ~est.flat
            return np.where(ok, value - half, np.nan), np.where(ok, value + half, np.nan)
        a, b = est.bounds
        u = np.clip((value - a) / (b - a), 0.0, 1.0)
        v = est.variance / (b - a) ** 2
        # below the most independent pairs could vary, u (1 - u) / n, a variance is raised toward it as by one
        # degree of freedom of that worst case: few base tasks of a skewed measure understate its spread
        if worst_case:
            worst = u * (1 - u) / est.units
            v = np.maximum(v, (df * v + WORST_CASE_WEIGHT * worst) / (df + WORST_CASE_WEIGHT))
        n_eff = u * (1 - u) / v
        centre = (u + q**2 / (2 * n_eff)) / (1 + q**2 / n_eff)
        half = q / (1 + q**2 / n_eff) * np.sqrt(u * (1 - u) / n_eff + q**2 / (4 * n_eff**2))
        low, high = centre - half, centre + half
        # every pair the same: Wilson's bound for none of G base tasks deviating
        flat = est.flat | (u * (1 - u) <= 0) | ~(v > 0)
        w = q**2 / (est.clusters + q**2)
        low = np.where(flat, u - w * u, low)
        high = np.where(flat, u + w * (1 - u), high)
        low, high = np.where(few, 0.0, low), np.where(few, 1.0, high)
        low, high = a + (b - a) * np.clip(low, 0, 1), a + (b - a) * np.clip(high, 0, 1)
    undefined = np.isnan(value)
    return np.where(undefined, np.nan, low), np.where(undefined, np.nan, high)


@dataclass
class Parts:
    """A measure's estimate per group and, for a signed sum of several ratios, each ratio's and how their
    estimates covary (from the same base-task influences)."""

    total: Estimates
    terms: list[tuple[int, Estimates]]
    correlation: np.ndarray | None  # (terms, terms, groups)
    paired: bool = False
    """A paired difference (its pieces are each ratio's difference between two sides)."""


def pieces(measure: Measure) -> list[tuple[int, Measure]]:
    """The signed pieces an interval combines: each ratio of a sum on one side; for a paired difference each
    ratio's difference between the sides (A - B over the same pairs, so what both sides share cancels in it)."""
    sides = [term[2] if len(term) > 2 else 0 for term in measure.terms]
    if set(sides) == {0, 1}:
        half = len(measure.terms) // 2
        layout = [(s, t) for s, t, _ in measure.terms[:half]] == [(-s, t) for s, t, _ in measure.terms[half:]]
        if sides != [0] * half + [1] * half or not layout:
            raise ValueError(f"{measure.name}: a paired difference's terms are A's then B's, as Measure.minus makes")
        return [(sign, Measure(measure.name, ((1, term, 0), (-1, term, 1)))) for sign, term, _ in measure.terms[:half]]
    return [(sign, Measure(measure.name, ((1, term, *side),))) for sign, term, *side in measure.terms]


def parts(frame: pd.DataFrame, measure: Measure, grouping: Grouping, suffixes: Sequence[str] = ("",)) -> Parts:
    total = estimate(frame, measure, grouping, suffixes=suffixes)
    signed = pieces(measure)
    paired = {term[2] if len(term) > 2 else 0 for term in measure.terms} == {0, 1}
    if len(signed) == 1:
        return Parts(total, [(1, total)], None, paired)
    terms = [(sign, estimate(frame, piece, grouping, suffixes=suffixes)) for sign, piece in signed]
    k = len(terms)
    correlation = np.zeros((k, k, grouping.n_groups))
    for i in range(k):
        for j in range(k):
            (_, ei), (_, ej) = terms[i], terms[j]
            cov = grouping.per_group(ei.cells * ej.cells)
            scale = np.sqrt(ei.cluster_variance * ej.cluster_variance)
            correlation[i, j] = np.clip(np.divide(cov, scale, where=scale > 0, out=np.zeros_like(cov)), -1, 1)
    return Parts(total, terms, correlation, paired)


def _combined(p: Parts, level: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MOVER (Zou & Donner): a signed sum's limits from its ratios' limits and their correlation."""
    value = p.total.value
    down, up = [], []
    for sign, est in p.terms:
        low, high = ratio_interval(est, level, worst_case=not p.paired)
        below, above = est.value - low, high - est.value
        down.append(below if sign > 0 else above)
        up.append(above if sign > 0 else below)
    signs = [s for s, _ in p.terms]
    width_down = np.zeros_like(value)
    width_up = np.zeros_like(value)
    for i in range(len(p.terms)):
        for j in range(len(p.terms)):
            r = 1.0 if i == j else signs[i] * signs[j] * p.correlation[i, j]
            width_down = width_down + r * down[i] * down[j]
            width_up = width_up + r * up[i] * up[j]
    low = value - np.sqrt(np.maximum(width_down, 0))
    high = value + np.sqrt(np.maximum(width_up, 0))
    bounds = p.total.bounds
    if bounds is None:  # a measure without a range: the t interval of the sum's own variance
        return ratio_interval(p.total, level)
    # every pair's sum the same (dSR of concordant pairs): its ratios move together and their limits cancel, so
    # the sum keeps at least its own bound for none of G base tasks differing
    flat_low, flat_high = ratio_interval(p.total, level)
    low = np.where(p.total.flat, np.minimum(low, flat_low), low)
    high = np.where(p.total.flat, np.maximum(high, flat_high), high)
    few = p.total.clusters < 2
    low = np.where(few, bounds[0], np.clip(low, *bounds))
    high = np.where(few, bounds[1], np.clip(high, *bounds))
    return low, high


def interval(p: Parts | Estimates, level: float | np.ndarray = LEVEL) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) per group (NaN where the value is undefined, or for a measure without a range where no
    interval can be given): one ratio's score interval, a signed sum's combined from its ratios' (MOVER)."""
    if isinstance(p, Estimates):
        return ratio_interval(p, level)
    if p.correlation is None:
        return ratio_interval(p.total, level, worst_case=not p.paired)
    low, high = _combined(p, level)
    undefined = np.isnan(p.total.value)
    return np.where(undefined, np.nan, low), np.where(undefined, np.nan, high)


def p_value(p: Parts | Estimates, null: float = 0.0, steps: int = 40) -> np.ndarray:
    """Two-sided p-value of the value being ``null``: one minus the lowest level whose interval holds it (so
    the null lies outside the 95 % interval exactly where p < 0.05). NaN where the value is undefined or no
    interval can be given (a measure without a range whose pairs all agree); 1 with fewer than two base tasks."""
    est = p if isinstance(p, Estimates) else p.total
    low_level = np.zeros_like(est.value)
    high_level = np.full_like(est.value, 1 - 1e-12)
    for _ in range(steps):  # the interval widens with its level: bisect for where it reaches the null
        middle = (low_level + high_level) / 2
        low, high = interval(p, middle)
        inside = (low <= null) & (null <= high)
        high_level = np.where(inside, middle, high_level)
        low_level = np.where(inside, low_level, middle)
    out = np.where(high_level < 1e-9, 1.0, 1 - high_level)  # held at every level: the value is the null
    out = np.where(est.clusters < 2, 1.0, out)
    low, _ = interval(p, LEVEL)
    out = np.where(np.isnan(low), np.nan, out)  # no interval (a measure without a range, all alike): no test
    return np.where(np.isnan(est.value), np.nan, out)


def holm(p: Sequence[float]) -> np.ndarray:
    """Holm's step-down adjustment (NaN entries stay NaN and do not count among the tests)."""
    p = np.asarray(p, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    tested = np.flatnonzero(~np.isnan(p))
    order = tested[np.argsort(p[tested], kind="stable")]
    running = 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * p[index]))
        out[index] = running
    return out


def cluster_ids(frame: pd.DataFrame) -> np.ndarray:
    """Each row's base task as an int (every row its own where the frame names none)."""
    keys = [k for k in CLUSTER_KEYS if k in frame.columns]
    if not keys:
        return np.arange(len(frame), dtype=np.int64)
    return combined_codes(frame, keys)[0]


def combined_codes(frame: pd.DataFrame, keys: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Each row's code for its combination of ``keys`` (0..k-1, missing values a value of their own), and the
    first row of each code."""
    if not len(frame):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    combined = np.zeros(len(frame), dtype=np.int64)
    for key in keys:
        codes, uniques = pd.factorize(frame[key], use_na_sentinel=False)
        combined = combined * (len(uniques) + 1) + codes
        combined = np.unique(combined, return_inverse=True)[1].astype(np.int64)  # keep the radix small
    _, first, codes = np.unique(combined, return_index=True, return_inverse=True)
    return codes.astype(np.int64), first
