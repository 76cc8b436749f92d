"""Aggregates over the per-pair frame of :func:`~conflictbench.metrics.evaluate_pairs`.

Rates are fractions in [0, 1] with their counts: PCSR = PCSR_k / pairs, RGSR = RGSR_k / pairs,
dSR = PCSR - RGSR, FR = FR_k / FR_n with FR_n = |D_Q| and FR_k = |D_QF|. A reference reused by
k pairs counts k times, because every row is a pair. Each process measure ``m`` gets its mean
over the pairs where it is defined (``m``, ``m_n``) and over the qualified failures D_QF only
(``m_qf``, ``m_qf_n``). Undefined values are NaN with a count of 0, never an exception. Every
measure ``X`` also has its 95 % interval ``X_lo``, ``X_hi`` and the base tasks it rests on,
``X_clusters`` (:mod:`.intervals`); P0 - P1 differences are paired (:mod:`.paired`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from conflictbench.core import FAMILIES, LEVELS, LIBERO_SUITES, PROMPT_CONDITIONS

from .intervals import Bounds
from .measures import PCSR, RGSR, check_ranges, group_index, intervals, metric_measure, report_measures
from .paired import DIFFERENCE_SUFFIXES, EXPERIMENT_KEYS, SIDE_COLUMNS, SIDES, differences, match

#: Grouping keys the report uses; ``model`` is the policy, told apart by settings when needed.
GROUPINGS = {
    "model": ("model", "prompt"),
    "family": ("model", "prompt", "family"),
    "level": ("model", "prompt", "level"),
    "family_level": ("model", "prompt", "family", "level"),
    "suite": ("model", "prompt", "suite"),
    "case": ("model", "prompt", "suite", "task_id", "case_id", "family", "level"),
}
#: Keys that make a P0 conflict episode and a P1 one the same experiment apart from the prompt.
PROMPT_PAIR_KEYS = ("policy", "config_hash", *(k for k in EXPERIMENT_KEYS if k != "prompt"))
_ORDER = {"family": FAMILIES, "level": LEVELS, "prompt": PROMPT_CONDITIONS, "suite": LIBERO_SUITES}


def with_model(frame: pd.DataFrame) -> pd.DataFrame:
    """Add ``model``: the policy name; where one policy ran in several variants, plus the settings in which
    they differ (``random seed=1``), or its settings hash where those do not tell them apart (other code,
    another simulator, or a store written before settings were kept)."""
    if "model" in frame.columns:
        return frame
    out = frame.copy()
    if frame.empty:
        out["model"] = pd.Series([], dtype=object)
        return out
    settings = frame["policy_settings"] if "policy_settings" in frame.columns else pd.Series("", index=frame.index)
    settings = settings.map(lambda s: s if isinstance(s, str) else "")  # NaN (a frame read back from CSV): none
    labels: dict[tuple[str, str], str] = {}
    for policy, group in frame.assign(policy_settings=settings).groupby("policy", sort=False):
        group = group.sort_values("policy_settings", ascending=False, kind="stable")  # settings before "" rows
        variants = group.drop_duplicates("config_hash")[["config_hash", "policy_settings"]].itertuples(index=False)
        labels.update(_variant_labels(str(policy), list(variants)))
    keys = zip(frame["policy"].astype(str), frame["config_hash"].astype(str), strict=True)
    out["model"] = [labels[key] for key in keys]
    return out


def _variant_labels(policy: str, variants: list) -> dict[tuple[str, str], str]:
    """(policy, config_hash) -> its label among ``variants`` (config_hash, settings JSON) of one policy."""
    if len(variants) == 1:
        return {(policy, str(variants[0].config_hash)): policy}
    parsed = [json.loads(v.policy_settings) if v.policy_settings else None for v in variants]
    if all(p is not None for p in parsed):
        names = sorted({name for p in parsed for name in p})
        differing = [n for n in names if len({json.dumps(p.get(n), sort_keys=True) for p in parsed}) > 1]
        texts = [" ".join(f"{n}={_short(p.get(n))}" for n in differing) for p in parsed]
        if differing and len(set(texts)) == len(texts):
            return {(policy, str(v.config_hash)): f"{policy} {text}" for v, text in zip(variants, texts, strict=True)}
    return {(policy, str(v.config_hash)): f"{policy}[{str(v.config_hash)[:6]}]" for v in variants}


def _short(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, sort_keys=True)
    return text if len(text) <= 24 else text[:21] + "..."


def qualified_failure_mask(frame: pd.DataFrame) -> pd.Series:
    """D_QF: the reference succeeded and the conflict rollout did not complete the original goal."""
    return frame["reference_success"].astype(bool) & ~frame["conflict_success"].astype(bool)


def sort_groups(frame: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Families, levels, prompts and suites in the paper's order; anything else alphabetically."""
    if frame.empty:
        return frame.reset_index(drop=True)

    def key(column: pd.Series) -> pd.Series:
        order = _ORDER.get(column.name)
        if order is not None:
            return column.map(lambda v: (order.index(v), "") if v in order else (len(order), str(v)))
        return column.map(lambda v: (1, "") if v is None or (isinstance(v, float) and math.isnan(v)) else (0, v))

    return frame.sort_values(list(by), key=key, kind="stable").reset_index(drop=True)


def aggregate(
    frame: pd.DataFrame, by: Sequence[str], metrics: Sequence[str], ranges: Mapping[str, Bounds] | None = None
) -> pd.DataFrame:
    """One row per group of ``by``: outcome rates with counts, then each metric over all pairs and D_QF; each
    measure ``X`` with its 95 % interval ``X_lo``, ``X_hi`` and the base tasks it rests on, ``X_clusters``
    (:mod:`.intervals`), and ``clusters``, the base tasks of the group's pairs. ``ranges``: a metric's bounds
    (name -> (low, high); a metric not named has none, so a t interval)."""
    frame = with_model(frame) if "model" in by else frame
    columns = aggregate_columns(by, metrics)
    if frame.empty:
        return pd.DataFrame({c: pd.Series([], dtype=object if c in by else np.float64) for c in columns})
    check_ranges(frame, ranges or {})
    group, keys = group_index(frame, by)
    out = intervals(frame, by, report_measures(metrics, ranges), groups=(group, keys))
    ref = frame["reference_success"].to_numpy(dtype=bool)
    con = frame["conflict_success"].to_numpy(dtype=bool)
    qf = ref & ~con

    def count(weights) -> np.ndarray:
        return np.bincount(group, weights, minlength=len(keys)).round().astype(np.int64)

    out["pairs"] = count(None)
    out["PCSR_k"] = count(ref)
    out["RGSR_k"] = count(con)
    out["FR_k"] = count(qf)
    out["FR_n"] = count(ref)
    for m in metrics:
        defined = np.isfinite(frame[m].to_numpy(dtype=np.float64))
        out[f"{m}_n"] = count(defined)
        out[f"{m}_qf_n"] = count(defined & qf)
    return sort_groups(out[columns], by)


def aggregate_columns(by: Sequence[str], metrics: Sequence[str]) -> list[str]:
    def measure(x: str) -> list[str]:
        return [x, f"{x}_lo", f"{x}_hi", f"{x}_clusters"]

    columns = [*by, "pairs", "clusters", "PCSR_k", *measure("PCSR"), "RGSR_k", *measure("RGSR"), *measure("dSR")]
    columns += ["FR_k", "FR_n", *measure("FR")]
    for m in metrics:
        columns += [*measure(m), f"{m}_n", *measure(f"{m}_qf"), f"{m}_qf_n"]
    return columns


def prompt_couples(frame: pd.DataFrame, metrics: Sequence[str]) -> pd.DataFrame:
    """P0 and P1 pairs of the same conflict case, init state, seed, step budget and policy settings, side by
    side: the keys, ``model``, ``family``, ``level``, each side's ``reference_success`` and
    ``conflict_success`` and each metric (NaN unless defined under both), suffixed ``_p0`` and ``_p1``, and
    ``X_diff`` = P0 - P1 for ``PCSR`` and ``RGSR`` (reference / conflict success as 0/1) and each metric."""
    frame = with_model(frame)
    columns = [*PROMPT_PAIR_KEYS, "model", "family", "level"]
    sides = [*SIDE_COLUMNS, *metrics]
    columns += [f"{x}_{s}" for x in sides for s in ("p0", "p1")]
    columns += [f"{x}_diff" for x in ("PCSR", "RGSR", *metrics)]
    p0 = frame[frame["prompt"] == "p0"] if len(frame) else frame
    p1 = frame[frame["prompt"] == "p1"] if len(frame) else frame
    if p0.empty or p1.empty:
        return pd.DataFrame({c: pd.Series([], dtype=object if c in columns[:13] else np.float64) for c in columns})
    matched = match(p0, p1, PROMPT_PAIR_KEYS, metrics, carry=PROMPT_PAIR_KEYS + ("model",)).frame
    matched = matched.rename(columns={f"{x}{a}": f"{x}_{p}" for x in sides for a, p in zip(SIDES, ("p0", "p1"))})
    for x, column in (("PCSR", "reference_success"), ("RGSR", "conflict_success"), *((m, m) for m in metrics)):
        matched[f"{x}_diff"] = matched[f"{column}_p0"].astype(np.float64) - matched[f"{column}_p1"].astype(np.float64)
    for c in columns:
        if c not in matched.columns:
            matched[c] = None
    return sort_groups(matched[columns], ["model", "suite", "task_id", "case_id", "init_state"])


def prompt_differences(
    couples: pd.DataFrame,
    metrics: Sequence[str],
    by: Sequence[str] = ("model",),
    ranges: Mapping[str, Bounds] | None = None,
) -> pd.DataFrame:
    """P0 - P1 per group over its couples, for PCSR, RGSR and each metric, as :func:`.paired.differences`
    gives it: ``pairs``, ``clusters``, and per measure the difference, each side's value, the 95 % interval
    clustered by base task, the p-value and the base tasks (``X``, ``X_a``, ``X_b``, ``X_lo``, ``X_hi``,
    ``X_p``, ``X_clusters``)."""
    ranges = ranges or {}
    measures = [PCSR, RGSR, *(metric_measure(m, ranges.get(m)) for m in metrics)]
    if couples.empty:
        names = ["pairs", "clusters"] + [f"{x.name}{s}" for x in measures for s in DIFFERENCE_SUFFIXES]
        return pd.DataFrame({c: pd.Series([], dtype=object if c in by else np.float64) for c in [*by, *names]})
    out = differences(couples, by, measures, suffixes=("_p0", "_p1"))
    return sort_groups(out, by)
