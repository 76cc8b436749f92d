"""Aggregates over the per-pair frame of :func:`~conflictbench.metrics.evaluate_pairs`.

Rates are fractions in [0, 1] with their counts: PCSR = PCSR_k / pairs, RGSR = RGSR_k / pairs,
dSR = PCSR - RGSR, FR = FR_k / FR_n with FR_n = |D_Q| and FR_k = |D_QF|. A reference reused by
k pairs counts k times, because every row is a pair. Each process measure ``m`` gets its mean
over the pairs where it is defined (``m``, ``m_n``) and over the qualified failures D_QF only
(``m_qf``, ``m_qf_n``). Undefined values are NaN with a count of 0, never an exception.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from conflictbench.core import FAMILIES, LEVELS, LIBERO_SUITES, PROMPT_CONDITIONS

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
PROMPT_PAIR_KEYS = ("policy", "config_hash", "suite", "task_id", "init_state", "case_id", "seed")
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


def _grouped(work: pd.DataFrame, by: Sequence[str]):
    # dropna=False: a group whose key is missing (e.g. no family) is still a row
    return work.groupby(list(by), dropna=False, sort=False)


def _with_keys(parts: dict[str, pd.Series], by: Sequence[str]) -> pd.DataFrame:
    out = pd.DataFrame(parts)
    out.index.names = list(by)
    return out.reset_index()


def aggregate(frame: pd.DataFrame, by: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    """One row per group of ``by``: outcome rates with counts, then each metric over all pairs and D_QF."""
    frame = with_model(frame) if "model" in by else frame
    columns = [*by, "pairs", "PCSR_k", "PCSR", "RGSR_k", "RGSR", "dSR", "FR_k", "FR_n", "FR"]
    for m in metrics:
        columns += [m, f"{m}_n", f"{m}_qf", f"{m}_qf_n"]
    if frame.empty:
        return pd.DataFrame({c: pd.Series([], dtype=object if c in by else np.float64) for c in columns})
    ref = frame["reference_success"].astype(bool)
    con = frame["conflict_success"].astype(bool)
    qf = ref & ~con
    work = frame[list(by)].assign(_ref=ref, _con=con, _qf=qf)
    for m in metrics:
        work[m] = frame[m].astype(np.float64)
        work[f"{m}_qf"] = work[m].where(qf)
    gb = _grouped(work, by)
    parts = {
        "pairs": gb.size(),
        "PCSR_k": gb["_ref"].sum(),
        "RGSR_k": gb["_con"].sum(),
        "FR_k": gb["_qf"].sum(),
        "FR_n": gb["_ref"].sum(),
    }
    for m in metrics:
        parts[m] = gb[m].mean()
        parts[f"{m}_n"] = gb[m].count()
        parts[f"{m}_qf"] = gb[f"{m}_qf"].mean()
        parts[f"{m}_qf_n"] = gb[f"{m}_qf"].count()
    out = _with_keys(parts, by)
    for c in (
        "pairs",
        "PCSR_k",
        "RGSR_k",
        "FR_k",
        "FR_n",
        *(f"{m}_n" for m in metrics),
        *(f"{m}_qf_n" for m in metrics),
    ):
        out[c] = out[c].astype(np.int64)
    out["PCSR"] = out["PCSR_k"] / out["pairs"]
    out["RGSR"] = out["RGSR_k"] / out["pairs"]
    out["dSR"] = out["PCSR"] - out["RGSR"]
    out["FR"] = np.where(out["FR_n"] > 0, out["FR_k"] / out["FR_n"].where(out["FR_n"] > 0, 1), np.nan)
    return sort_groups(out[columns], by)


def prompt_couples(frame: pd.DataFrame, metrics: Sequence[str]) -> pd.DataFrame:
    """P0 and P1 pairs of the same conflict case, init state and policy settings, side by side.

    Columns: the keys, ``model``, ``family``, ``level``, and for each measure ``X_p0``, ``X_p1``
    and ``X_diff`` = P0 - P1, where X is ``PCSR``/``RGSR`` (reference / conflict success as 0/1)
    or a metric (NaN unless defined in both).
    """
    frame = with_model(frame)
    measures = ["PCSR", "RGSR", *metrics]
    columns = [*PROMPT_PAIR_KEYS, "model", "family", "level"]
    columns += [f"{x}_{s}" for x in measures for s in ("p0", "p1", "diff")]
    values = (
        frame.assign(
            PCSR=frame["reference_success"].astype(np.float64), RGSR=frame["conflict_success"].astype(np.float64)
        )
        if len(frame)
        else frame
    )
    p0 = values[values["prompt"] == "p0"] if len(frame) else frame
    p1 = values[values["prompt"] == "p1"] if len(frame) else frame
    if p0.empty or p1.empty:
        return pd.DataFrame({c: pd.Series([], dtype=object if c in columns[:10] else np.float64) for c in columns})
    keys = list(PROMPT_PAIR_KEYS)
    left = p0[[*keys, "model", "family", "level", *measures]].drop_duplicates(keys)
    right = p1[[*keys, *measures]].drop_duplicates(keys)
    merged = left.merge(right, on=keys, suffixes=("_p0", "_p1"), how="inner")
    for x in measures:
        merged[f"{x}_p0"] = merged[f"{x}_p0"].astype(np.float64)
        merged[f"{x}_p1"] = merged[f"{x}_p1"].astype(np.float64)
        merged[f"{x}_diff"] = merged[f"{x}_p0"] - merged[f"{x}_p1"]
    return sort_groups(merged[columns], ["model", "suite", "task_id", "case_id", "init_state"])


def prompt_differences(couples: pd.DataFrame, metrics: Sequence[str], by: Sequence[str] = ("model",)) -> pd.DataFrame:
    """Mean paired P0 - P1 difference per group, with its count and a 95% interval half-width.

    The half-width is 1.96 * sd / sqrt(n) (normal approximation; NaN when n < 2).
    """
    measures = ["PCSR", "RGSR", *metrics]
    columns = [*by, "couples"] + [f"{x}_{s}" for x in measures for s in ("diff", "n", "ci95")]
    if couples.empty:
        return pd.DataFrame({c: pd.Series([], dtype=object if c in by else np.float64) for c in columns})
    gb = _grouped(couples, by)
    parts = {"couples": gb.size()}
    for x in measures:
        d = gb[f"{x}_diff"]
        n = d.count()
        parts[f"{x}_diff"] = d.mean()
        parts[f"{x}_n"] = n
        parts[f"{x}_ci95"] = (1.96 * d.std(ddof=1) / np.sqrt(n)).where(n >= 2)
    out = _with_keys(parts, by)
    return sort_groups(out[columns], by)
