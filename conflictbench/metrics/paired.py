"""Paired comparisons: the pairs two sides (two models, two settings, P0 and P1) both played, matched on
everything that makes them the same experiment, and each measure's difference with its interval and test.

A side is a set of rows of the per-pair frame. Matching keeps, for each measure, only what both sides can
be compared on: a metric counts in a matched pair where it is defined for both sides; FR compares each
side's qualified failures among its own successful references (a ratio on each side, over the same pairs).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .intervals import CLUSTER_KEYS, Grouping, Measure, cluster_ids, estimate, holm, interval, p_value, parts
from .measures import group_index

#: What makes two pairs the same experiment, whatever is compared (the prompt too, unless it is compared).
EXPERIMENT_KEYS = ("suite", "task_id", "case_id", "conflict_suite", "init_state", "prompt", "seed", "max_steps")
#: Why a pair has no counterpart: the first of these (in order) the other side never played with the rest.
REASONS = {
    "case_id": "case not played",
    "conflict_suite": "other suite version",
    "init_state": "initial state not played",
    "prompt": "prompt condition not played",
    "seed": "other seed",
    "max_steps": "other step budget",
}
SIDE_COLUMNS = ("reference_success", "conflict_success")
SIDES = ("_a", "_b")
#: The columns :func:`differences` gives each measure X, after its name.
DIFFERENCE_SUFFIXES = ("", "_a", "_b", "_lo", "_hi", "_p", "_clusters", "_n")


@dataclass
class Matched:
    """The matched pairs (keys, ``family``, ``level`` and each side's columns suffixed ``_a``/``_b``), and
    per side how many pairs found no counterpart, by reason."""

    frame: pd.DataFrame
    unmatched_a: Counter = field(default_factory=Counter)
    unmatched_b: Counter = field(default_factory=Counter)


def present_keys(a: pd.DataFrame, b: pd.DataFrame, keys: Sequence[str]) -> list[str]:
    """The keys both frames have (a frame of an older store may lack the newer ones)."""
    return [k for k in keys if k in a.columns and k in b.columns]


def _key_text(value) -> str:
    """A key as comparable text: None and NaN alike, 300 and 300.0 (a store's integer read back as a float) alike."""
    if value is None or (isinstance(value, float | np.floating) and np.isnan(value)):
        return "\x00"
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, int | np.integer) or (isinstance(value, float | np.floating) and float(value).is_integer()):
        return str(int(value))
    return str(value)


def _key_frame(frame: pd.DataFrame, keys: Sequence[str]) -> pd.DataFrame:
    """The keys as comparable text, so that merging never trips over dtypes."""
    return pd.DataFrame({k: frame[k].astype(object).map(_key_text) for k in keys}, index=frame.index)


def _reasons(rows: pd.DataFrame, other: pd.DataFrame, keys: Sequence[str]) -> Counter:
    reasons: Counter = Counter()
    if rows.empty:
        return reasons
    order = ["suite", "task_id", *[k for k in REASONS if k in keys]]
    order = [k for k in order if k in keys]
    remaining = rows
    for depth in range(1, len(order) + 1):
        prefix = order[:depth]
        seen = other[prefix].drop_duplicates()
        hit = remaining[prefix].merge(seen, on=prefix, how="left", indicator=True)["_merge"].to_numpy() == "both"
        lost = remaining[~hit]
        if len(lost) and order[depth - 1] in REASONS:
            reasons[REASONS[order[depth - 1]]] += len(lost)
        elif len(lost):
            reasons["case not played"] += len(lost)  # another base task altogether
        remaining = remaining[hit]
        if remaining.empty:
            break
    return reasons


def match(
    a: pd.DataFrame, b: pd.DataFrame, keys: Sequence[str], metrics: Sequence[str], carry: Sequence[str] = ()
) -> Matched:
    """Pairs of ``a`` and ``b`` equal on ``keys`` side by side (each side's first where one is stored twice),
    with side A's base task, case, initial state, family, level and ``carry`` columns."""
    keys = present_keys(a, b, keys)
    ka, kb = _key_frame(a, keys), _key_frame(b, keys)
    ka["_row_a"], kb["_row_b"] = np.arange(len(a)), np.arange(len(b))
    # a pair stored twice counts once, the same one whatever the frame's order (by its conflict episode)
    ka, kb = _first(ka, a, keys), _first(kb, b, keys)
    twice_a, twice_b = len(a) - len(ka), len(b) - len(kb)
    both = ka.merge(kb, on=keys, how="inner")
    ia, ib = both["_row_a"].to_numpy(), both["_row_b"].to_numpy()
    wanted = (*carry, *CLUSTER_KEYS, "case_id", "init_state", "family", "level")
    carried = [c for c in dict.fromkeys(wanted) if c in a.columns]
    out = a.iloc[ia][carried].reset_index(drop=True)
    for column in (*SIDE_COLUMNS, *metrics):
        left = a.iloc[ia][column].to_numpy()
        right = b.iloc[ib][column].to_numpy()
        if column in metrics:  # a metric is compared where both sides define it
            left, right = left.astype(np.float64), right.astype(np.float64)
            both_defined = np.isfinite(left) & np.isfinite(right)
            left, right = np.where(both_defined, left, np.nan), np.where(both_defined, right, np.nan)
        out[f"{column}_a"], out[f"{column}_b"] = left, right
    lost_a = ka[~ka["_row_a"].isin(ia)]
    lost_b = kb[~kb["_row_b"].isin(ib)]
    unmatched_a, unmatched_b = _reasons(lost_a, kb, keys), _reasons(lost_b, ka, keys)
    for counter, twice in ((unmatched_a, twice_a), (unmatched_b, twice_b)):
        if twice:
            counter["stored more than once (counted once)"] += twice
    return Matched(out, unmatched_a, unmatched_b)


def _first(keyed: pd.DataFrame, frame: pd.DataFrame, keys: Sequence[str]) -> pd.DataFrame:
    if "conflict_episode" in frame.columns:
        keyed = keyed.iloc[np.argsort(frame["conflict_episode"].astype(str).to_numpy(), kind="stable")]
    return keyed.drop_duplicates(keys)


def differences(
    matched: pd.DataFrame,
    by: Sequence[str],
    measures: Sequence[Measure],
    holm_within: bool = False,
    suffixes: Sequence[str] = SIDES,
) -> pd.DataFrame:
    """Per group of ``by``: ``pairs``, ``clusters``, then for each measure ``X`` (A - B): ``X`` the difference,
    ``X_a``, ``X_b`` (each side's value over the matched pairs), ``X_lo``, ``X_hi``, ``X_p`` (two-sided, at the
    null of no difference), ``X_clusters`` and ``X_n`` (the base tasks and pairs it rests on); with
    ``holm_within`` also ``X_p_holm``, Holm-adjusted among the groups. ``suffixes``: the sides' column suffixes."""
    group, keys = group_index(matched, by)
    grouping = Grouping.of(group, len(keys), cluster_ids(matched))
    out = keys.copy()
    out["pairs"] = np.bincount(group, minlength=len(keys))
    out["clusters"] = grouping.clusters()
    for measure in measures:
        found = parts(matched, measure.minus(), grouping, suffixes)
        est = found.total
        low, high = interval(found)
        out[measure.name] = est.value
        for side, suffix in zip(("a", "b"), suffixes):
            out[f"{measure.name}_{side}"] = estimate(matched, measure, grouping, suffixes=(suffix,)).value
        out[f"{measure.name}_lo"], out[f"{measure.name}_hi"] = low, high
        out[f"{measure.name}_p"] = p_value(found)
        if holm_within:
            out[f"{measure.name}_p_holm"] = holm(out[f"{measure.name}_p"])
        out[f"{measure.name}_clusters"] = est.clusters
        out[f"{measure.name}_n"] = est.units
    return out


def verdict(difference: float, p: float, alpha: float = 0.05) -> str:
    """ "A higher", "B higher" or "no detectable difference" (at ``alpha``; a NaN p, no test: no difference)."""
    if not (p == p) or not (difference == difference) or p >= alpha or difference == 0:
        return "no detectable difference"
    return "A higher" if difference > 0 else "B higher"
