"""The process measures (TAR, TS, Early20 TS, AMS) per pair, and the fast batch path.

:func:`evaluate_pairs` packs a chunk of pairs into flat arrays (each reference once, however many
conflicts reuse it) and runs the compiled kernels over the chunk in parallel; only per-pair
scalars are kept between chunks, so memory stays bounded whatever the number of pairs.
:func:`pair_metrics` is the same computation for one pair. Other registered metrics (plugins)
are called pair by pair through their ``compute(pair)``.
"""

from __future__ import annotations

import functools
import math
import warnings
from itertools import islice
from typing import Any, Iterable, Iterator, Sequence

import numpy as np
import pandas as pd

from conflictbench.core import EpisodeRecord, MetricSpec, Pair, UserError
from conflictbench.core.plugins import unknown_choice

from . import dtw as dtw_kernels
from . import kernels, plain
from .plain import EARLY_STEPS, EPS, SIGMA

BUILTIN_METRICS = ("tar", "early20_ts", "ts", "ams")  # the paper's column order
DESCRIPTIONS = {
    "tar": "Target Approach Ratio: how far the conflict rollout still closed in on the original targets, "
           "relative to the reference (A-/A+, clipped to [0,1]); lower = stopped pursuing the invalid goal",
    "ts": f"Trajectory Similarity: exp(-DTW/(sigma*L)) of the end-effector paths, sigma={SIGMA} m; "
          "lower = the conflict rollout left the reference path",
    "early20_ts": f"TS over the initial position and the first min({EARLY_STEPS}, H) steps of each rollout",
    "ams": "Action Magnitude Suppression: 1 - I(tau-)/I(tau+) over the first six action dims, scaled by the "
           "reference's RMS per dim; higher = moved less than in the reference",
}
#: Identifies each pair in :func:`evaluate_pairs`'s frame (taken from the conflict episode).
KEY_COLUMNS = ("policy", "config_hash", "suite", "task_id", "init_state", "prompt", "seed", "case_id",
               "family", "level")
CHUNK_PAIRS = 2048


# -- the registered compute functions (also the slow path for a caller holding a Pair) ----------
def compute_tar(pair: Pair) -> float | None:
    return _one_pair(pair.reference, pair.conflict)["tar"]


def compute_ts(pair: Pair) -> float | None:
    return _one_pair(pair.reference, pair.conflict)["ts"]


def compute_early20_ts(pair: Pair) -> float | None:
    return _one_pair(pair.reference, pair.conflict)["early20_ts"]


def compute_ams(pair: Pair) -> float | None:
    return _one_pair(pair.reference, pair.conflict)["ams"]


COMPUTE = {"tar": compute_tar, "ts": compute_ts, "early20_ts": compute_early20_ts, "ams": compute_ams}
_BATCHED = {fn: name for name, fn in COMPUTE.items()}  # recognised by identity in evaluate_pairs


def dtw(p: np.ndarray, q: np.ndarray, *, kernel: str = "matrix") -> tuple[float, int]:
    """(DTW cost, L) between two end-effector paths (n x 3, m x 3); ``dtw.py`` states the tie rule.

    ``kernel``: "matrix" (the fast one), "lex" (O(n + m) memory) or "plain" (the specification).
    """
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
    if kernel == "plain" or not kernels.available():
        return plain.dtw(p, q)
    a = [np.ascontiguousarray(p[:, d]) for d in range(3)]
    b = [np.ascontiguousarray(q[::-1, d]) for d in range(3)]
    if kernel == "lex":
        cost, cells = dtw_kernels.dtw_lex(*a, *b)
    elif kernel == "matrix":
        cost, cells = dtw_kernels.dtw_matrix(*a, *b, *dtw_kernels.workspace(len(p) * len(q), len(p) + len(q)), 1)
    else:
        raise ValueError(f"unknown DTW kernel {kernel!r}")
    return float(cost), int(cells)


# -- packing -----------------------------------------------------------------------------------
def _points(record: EpisodeRecord) -> np.ndarray:
    return np.asarray(record.eef_pos, dtype=np.float64).reshape(-1, 3)


def _actions(record: EpisodeRecord) -> np.ndarray:
    """Actions as rows; a malformed array (fewer than six dims) counts as empty."""
    actions = np.asarray(record.actions, dtype=np.float64)
    if actions.ndim != 2 or actions.shape[1] < 6:
        return np.zeros((0, 6))
    return actions


def _stack(arrays: list[np.ndarray], width: int) -> np.ndarray:
    """Row-concatenate, keeping only the first ``width`` columns when widths differ."""
    if not arrays:
        return np.zeros((0, width))
    if len({a.shape[1] for a in arrays}) > 1:
        arrays = [a[:, :width] for a in arrays]
    return np.ascontiguousarray(np.concatenate(arrays))


def _targets(record: EpisodeRecord, states: int) -> tuple[np.ndarray, int]:
    """Target positions as rows of 3 and K; K = 0 (undefined TAR) if they do not match the states."""
    tp = np.asarray(record.target_pos, dtype=np.float64)
    if tp.ndim != 3 or tp.shape[0] != states or tp.shape[2] != 3 or states == 0:
        return np.zeros((0, 3)), 0
    return tp.reshape(-1, 3), tp.shape[1]


def _offsets(lengths: Sequence[int]) -> np.ndarray:
    out = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(lengths, out=out[1:])
    return out


def _builtin_batch(references: Sequence[EpisodeRecord], conflicts: Sequence[EpisodeRecord]) -> dict[str, np.ndarray]:
    """TAR, TS, Early20 TS and AMS of aligned pairs; nan where undefined."""
    if not kernels.available():  # pragma: no cover - installs without numba
        rows = [plain.pair_metrics(r, c) for r, c in zip(references, conflicts)]
        return {name: np.array([math.nan if row[name] is None else row[name] for row in rows], dtype=np.float64)
                for name in BUILTIN_METRICS}
    index: dict[int, int] = {}
    rollouts: list[EpisodeRecord] = []
    for record in (*references, *conflicts):
        if id(record) not in index:  # a reference reused by many conflicts is packed once
            index[id(record)] = len(rollouts)
            rollouts.append(record)
    ref_idx = np.fromiter((index[id(r)] for r in references), dtype=np.int64, count=len(references))
    con_idx = np.fromiter((index[id(c)] for c in conflicts), dtype=np.int64, count=len(conflicts))

    points = [_points(r) for r in rollouts]
    eoff = _offsets([len(p) for p in points])
    eef = _stack(points, 3)
    actions = [_actions(r) for r in rollouts]
    aoff = _offsets([len(a) for a in actions])
    act = _stack(actions, 6)
    targets = [_targets(r, len(p)) for r, p in zip(rollouts, points)]
    toff = _offsets([len(t) for t, _ in targets])
    tgt = _stack([t for t, _ in targets], 3)
    k = np.array([kk for _, kk in targets], dtype=np.int64)

    with kernels.dynamic_schedule():
        ts, early, ams = kernels.pair_kernel(eef, eoff, act, aoff, ref_idx, con_idx, SIGMA, EARLY_STEPS + 1, EPS,
                                             kernels.threads())
    approach = kernels.approach_kernel(eef, eoff, tgt, toff, k)
    names = [frozenset(r.target_names) for r in rollouts]
    same_targets = np.fromiter((names[r] == names[c] for r, c in zip(ref_idx, con_idx)), dtype=bool,
                               count=len(ref_idx))
    a_ref, a_con = approach[ref_idx], approach[con_idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        tar = np.clip(a_con / np.maximum(a_ref, EPS), 0.0, 1.0)
    tar[~same_targets | ~np.isfinite(a_ref) | ~np.isfinite(a_con)] = math.nan
    return {"tar": tar, "ts": ts, "early20_ts": early, "ams": ams}


def _one_pair(reference: EpisodeRecord, conflict: EpisodeRecord) -> dict[str, float | None]:
    values = _builtin_batch([reference], [conflict])
    return {name: _value(values[name][0]) for name in BUILTIN_METRICS}


def _value(v: Any) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


# -- public API ----------------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def default_plugins():
    """The built-ins plus every installed plugin, created once (metrics' registry is then cached)."""
    import conflictbench

    return conflictbench.plugins()


def metric_specs(plugins=None, names: Sequence[str] | None = None) -> list[MetricSpec]:
    """The built-in process measures plus every registered metric, in registration order."""
    registered = (plugins or default_plugins()).metrics()
    specs = [registered.get(n) or MetricSpec(n, COMPUTE[n], DESCRIPTIONS[n], "conflictbench", "")
             for n in BUILTIN_METRICS]
    specs += [s for n, s in registered.items() if n not in BUILTIN_METRICS]
    if names is not None:
        by_name = {s.name: s for s in specs}
        for name in names:
            if name not in by_name:
                raise UserError(unknown_choice("metric", name, by_name))
        specs = [by_name[n] for n in names]
    return specs


def _chunks(references: Iterable[EpisodeRecord], conflicts: Iterable[EpisodeRecord],
            size: int) -> Iterator[tuple[list[EpisodeRecord], list[EpisodeRecord]]]:
    pairs = zip(references, conflicts, strict=True)
    while chunk := list(islice(pairs, size)):
        yield [r for r, _ in chunk], [c for _, c in chunk]


def _plugin_values(spec: MetricSpec, references: Sequence[EpisodeRecord], conflicts: Sequence[EpisodeRecord],
                   failed: set[str]) -> np.ndarray:
    out = np.full(len(references), math.nan)
    for i, (ref, con) in enumerate(zip(references, conflicts)):
        try:
            value = _value(spec.compute(Pair(reference=ref, conflict=con)))
        except Exception as exc:  # a broken third-party metric must not sink the report
            value = None
            if spec.name not in failed:
                failed.add(spec.name)
                warnings.warn(f"metric {spec.name!r} ({spec.plugin}) raised {type(exc).__name__}: {exc}; "
                              "counted as undefined", stacklevel=3)
        out[i] = math.nan if value is None else value
    return out


def evaluate_pairs(references: Iterable[EpisodeRecord], conflicts: Iterable[EpisodeRecord], *,
                   plugins=None, metrics: Sequence[str] | None = None,
                   chunk_size: int = CHUNK_PAIRS) -> pd.DataFrame:
    """One row per aligned (reference, conflict) pair: the pair's keys, both outcomes, every metric.

    Columns: :data:`KEY_COLUMNS` (from the conflict episode), ``reference_success``,
    ``conflict_success``, ``reference_episode``, ``conflict_episode``, then ``tar``, ``ts``,
    ``early20_ts``, ``ams`` and every other registered metric (or only ``metrics``), as float64
    with NaN where a measure is undefined. The inputs may be generators: they are consumed in
    chunks of ``chunk_size`` pairs, so only per-pair scalars are held.
    """
    specs = metric_specs(plugins, metrics)
    frames, failed = [], set()
    for refs, cons in _chunks(references, conflicts, chunk_size):
        columns: dict[str, Any] = {key: [getattr(c, key) for c in cons] for key in KEY_COLUMNS}
        columns["reference_success"] = np.fromiter((bool(r.success) for r in refs), dtype=bool, count=len(refs))
        columns["conflict_success"] = np.fromiter((bool(c.success) for c in cons), dtype=bool, count=len(cons))
        columns["reference_episode"] = [r.episode_id for r in refs]
        columns["conflict_episode"] = [c.episode_id for c in cons]
        builtin = None
        for spec in specs:
            if _BATCHED.get(spec.compute) == spec.name:
                builtin = builtin if builtin is not None else _builtin_batch(refs, cons)
                columns[spec.name] = builtin[spec.name]
            else:
                columns[spec.name] = _plugin_values(spec, refs, cons, failed)
        frames.append(pd.DataFrame(columns))
    if not frames:
        empty = {key: pd.Series([], dtype=object) for key in KEY_COLUMNS}
        empty.update({"reference_success": pd.Series([], dtype=bool), "conflict_success": pd.Series([], dtype=bool),
                      "reference_episode": pd.Series([], dtype=object),
                      "conflict_episode": pd.Series([], dtype=object)})
        empty.update({s.name: pd.Series([], dtype=np.float64) for s in specs})
        return pd.DataFrame(empty)
    return pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]


def pair_metrics(reference: EpisodeRecord, conflict: EpisodeRecord, *, plugins=None) -> dict[str, float | None]:
    """``tar``, ``ts``, ``early20_ts``, ``ams`` and every registered metric of one pair (None: undefined)."""
    row = evaluate_pairs([reference], [conflict], plugins=plugins).iloc[0]
    return {spec.name: _value(row[spec.name]) for spec in metric_specs(plugins)}
