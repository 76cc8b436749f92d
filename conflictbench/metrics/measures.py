"""The report's measures as ratios over the per-pair frame, and their intervals per group.

Columns read: ``reference_success``, ``conflict_success`` and each metric (NaN where undefined), with a
suffix when two sides of a paired comparison sit side by side (``_a``, ``_b``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from .intervals import Bounds, Grouping, Measure, Term, cluster_ids, combined_codes, interval, parts

RATE = (0.0, 1.0)


def _column(name: str):
    def read(frame: pd.DataFrame, suffix: str) -> np.ndarray:
        return frame[f"{name}{suffix}"].to_numpy(dtype=np.float64)

    return read


def _ones(frame: pd.DataFrame, suffix: str) -> np.ndarray:
    return np.ones(len(frame))


def _qualified_failure(frame: pd.DataFrame, suffix: str) -> np.ndarray:
    reference = frame[f"reference_success{suffix}"].to_numpy(dtype=bool)
    return (reference & ~frame[f"conflict_success{suffix}"].to_numpy(dtype=bool)).astype(np.float64)


def _defined(name: str, qualified_failures: bool):
    def weight(frame: pd.DataFrame, suffix: str) -> np.ndarray:
        defined = np.isfinite(frame[f"{name}{suffix}"].to_numpy(dtype=np.float64)).astype(np.float64)
        return defined * _qualified_failure(frame, suffix) if qualified_failures else defined

    return weight


def _value(name: str, qualified_failures: bool):
    weight = _defined(name, qualified_failures)

    def numerator(frame: pd.DataFrame, suffix: str) -> np.ndarray:
        return np.nan_to_num(frame[f"{name}{suffix}"].to_numpy(dtype=np.float64)) * weight(frame, suffix)

    return numerator


REFERENCE = Term(_column("reference_success"), _ones, RATE)
CONFLICT = Term(_column("conflict_success"), _ones, RATE)
PCSR = Measure("PCSR", ((1, REFERENCE),))
RGSR = Measure("RGSR", ((1, CONFLICT),))
DSR = Measure("dSR", ((1, REFERENCE), (-1, CONFLICT)))
FR = Measure("FR", ((1, Term(_qualified_failure, _column("reference_success"), RATE)),))
OUTCOMES = (PCSR, RGSR, DSR, FR)


def metric_measure(name: str, bounds: Bounds, qualified_failures: bool = False) -> Measure:
    """A metric's mean over the pairs where it is defined (``qualified_failures``: over D_QF only)."""
    term = Term(_value(name, qualified_failures), _defined(name, qualified_failures), bounds)
    return Measure(f"{name}_qf" if qualified_failures else name, ((1, term),))


def metric_ranges(metrics) -> dict[str, Bounds]:
    """Each registered metric's range, by name (:attr:`conflictbench.core.MetricSpec.bounds`)."""
    return {m.name: m.bounds for m in metrics}


def check_ranges(frame: pd.DataFrame, ranges: Mapping[str, Bounds], suffixes: Sequence[str] = ("",)) -> None:
    """A PluginError naming the metric where a value lies outside its declared range: its interval would be
    computed on a range that does not hold (a registration's ``bounds=``, or a ``"%"`` unit, is a promise)."""
    from conflictbench.core import PluginError

    for name, bounds in ranges.items():
        if bounds is None:
            continue
        low, high = bounds
        slack = 1e-9 * (high - low)
        for suffix in suffixes:
            if f"{name}{suffix}" not in frame.columns:
                continue
            values = frame[f"{name}{suffix}"].to_numpy(dtype=np.float64)
            outside = values[np.isfinite(values) & ((values < low - slack) | (values > high + slack))]
            if len(outside):
                raise PluginError(
                    f"metric {name!r} gave {len(outside)} value(s) outside its range [{low:g}, {high:g}] "
                    f"(e.g. {outside[0]:g}): its registration (bounds=, or unit '%' for [0, 1]) says they cannot be"
                )


def report_measures(metrics: Sequence[str], ranges: Mapping[str, Bounds] | None = None) -> list[Measure]:
    """PCSR, RGSR, dSR, FR, then each metric over all pairs and over D_QF (``ranges``: name -> bounds)."""
    ranges = ranges or {}
    out = list(OUTCOMES)
    for name in metrics:
        out += [metric_measure(name, ranges.get(name)), metric_measure(name, ranges.get(name), True)]
    return out


def group_index(frame: pd.DataFrame, by: Sequence[str]) -> tuple[np.ndarray, pd.DataFrame]:
    """Each row's group (0..k-1) and the groups' keys (missing values as None)."""
    if not by:
        return np.zeros(len(frame), dtype=np.int64), pd.DataFrame(index=[0])
    codes, first = combined_codes(frame, by)
    keys = frame[list(by)].iloc[first].reset_index(drop=True).astype(object)
    return codes, keys.where(keys.notna(), None)


def intervals(
    frame: pd.DataFrame,
    by: Sequence[str],
    measures: Sequence[Measure],
    suffixes: Sequence[str] = ("",),
    groups: tuple[np.ndarray, pd.DataFrame] | None = None,
) -> pd.DataFrame:
    """Per group of ``by``: ``clusters`` (base tasks among its pairs), then for each measure ``X`` its value,
    ``X_lo``, ``X_hi`` (the 95 % interval) and ``X_clusters`` (the base tasks it rests on). ``groups``: what
    :func:`group_index` gives for ``by``, where the caller has it already."""
    group, keys = groups if groups is not None else group_index(frame, by)
    grouping = Grouping.of(group, len(keys), cluster_ids(frame))
    out = keys.copy()
    out["clusters"] = grouping.clusters()
    for measure in measures:
        found = parts(frame, measure, grouping, suffixes)
        est = found.total
        low, high = interval(found)
        out[measure.name] = est.value
        out[f"{measure.name}_lo"] = low
        out[f"{measure.name}_hi"] = high
        out[f"{measure.name}_clusters"] = est.clusters
    return out
