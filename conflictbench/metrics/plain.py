"""The process measures written the plain way: one pair at a time, straight from the formulas.

This is the specification the compiled fast path (``kernels.py``) is tested against, the
baseline of ``benchmarks/bench_metrics.py``, and the fallback when numba is not installed. It
builds the full DTW cost matrix and fills the accumulated cost in a Python double loop.
Every function returns ``None`` where the measure is undefined.
"""

from __future__ import annotations

import math

import numpy as np

from conflictbench.core import EpisodeRecord

EPS = 1e-8
SIGMA = 0.10  # metres
EARLY_STEPS = 20
#: TAR needs a reference that really approached its targets: below this (metres), A-/A+ is noise.
MIN_APPROACH = 0.01


def _clip(value: float) -> float:
    return min(max(value, 0.0), 1.0)


def dtw(p: np.ndarray, q: np.ndarray) -> tuple[float, int]:
    """(accumulated cost, cells on the path) of DTW between two point sequences (n x 3, m x 3).

    Local cost: Euclidean distance. Among minimum-cost paths, the one with the fewest cells
    gives L (compare (cost, cells) lexicographically at every cell).
    """
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
    n, m = len(p), len(q)
    if n == 0 or m == 0:
        return math.nan, 0
    diff = p[:, None, :] - q[None, :, :]
    # (dx*dx + dy*dy) + dz*dz, written out so the rounding matches the compiled kernel exactly
    cost = np.sqrt(diff[..., 0] * diff[..., 0] + diff[..., 1] * diff[..., 1] + diff[..., 2] * diff[..., 2])
    acc = [[(math.inf, math.inf)] * m for _ in range(n)]
    for i in range(n):
        for j in range(m):
            if i == 0 and j == 0:
                best = (0.0, 0)
            else:
                candidates = []
                if i > 0:
                    candidates.append(acc[i - 1][j])
                if j > 0:
                    candidates.append(acc[i][j - 1])
                if i > 0 and j > 0:
                    candidates.append(acc[i - 1][j - 1])
                best = min(candidates)  # tuples: lowest cost first, then fewest cells
            acc[i][j] = (float(cost[i, j]) + best[0], best[1] + 1)
    total, cells = acc[n - 1][m - 1]
    return total, int(cells)


def trajectory_similarity(p: np.ndarray, q: np.ndarray, sigma: float = SIGMA) -> float | None:
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or len(q) == 0 or not (np.isfinite(p).all() and np.isfinite(q).all()):
        return None
    total, cells = dtw(p, q)
    return _clip(math.exp(-total / (sigma * cells)))


def ts(reference: EpisodeRecord, conflict: EpisodeRecord) -> float | None:
    return trajectory_similarity(conflict.eef_pos, reference.eef_pos)


def early20_ts(reference: EpisodeRecord, conflict: EpisodeRecord) -> float | None:
    """TS over the initial position and the positions after the first min(20, H) actions."""
    ref = np.asarray(reference.eef_pos).reshape(-1, 3)
    con = np.asarray(conflict.eef_pos).reshape(-1, 3)
    h_ref, h_con = len(ref) - 1, len(con) - 1
    return trajectory_similarity(con[: min(EARLY_STEPS, h_con) + 1], ref[: min(EARLY_STEPS, h_ref) + 1])


def approach(record: EpisodeRecord) -> float | None:
    """A = max(d_0 - min_t d_t, 0), d_t = min over targets of ||eef_t - obj_t||."""
    eef = np.asarray(record.eef_pos, dtype=np.float64).reshape(-1, 3)
    targets = np.asarray(record.target_pos, dtype=np.float64)
    if len(eef) == 0 or targets.ndim != 3 or targets.shape[0] != len(eef) or targets.shape[1] == 0:
        return None
    d = np.array([min(float(np.linalg.norm(eef[t] - obj)) for obj in targets[t]) for t in range(len(eef))])
    if not np.isfinite(d).all():
        return None
    return max(d[0] - d.min(), 0.0)


def tar(reference: EpisodeRecord, conflict: EpisodeRecord) -> float | None:
    if set(reference.target_names) != set(conflict.target_names):
        return None
    a_ref, a_con = approach(reference), approach(conflict)
    if a_ref is None or a_con is None or a_ref < MIN_APPROACH:
        return None
    return _clip(a_con / max(a_ref, EPS))


def ams(reference: EpisodeRecord, conflict: EpisodeRecord) -> float | None:
    ref = np.asarray(reference.actions, dtype=np.float64).reshape(-1, np.shape(reference.actions)[-1])[:, :6]
    con = np.asarray(conflict.actions, dtype=np.float64).reshape(-1, np.shape(conflict.actions)[-1])[:, :6]
    if len(ref) == 0 or len(con) == 0:
        return None
    gamma = np.sqrt(np.maximum(np.mean(ref**2, axis=0), EPS))
    i_ref = float(np.mean(np.linalg.norm(ref / gamma, axis=1)))
    i_con = float(np.mean(np.linalg.norm(con / gamma, axis=1)))
    if not (math.isfinite(i_ref) and math.isfinite(i_con)) or i_ref <= EPS:
        return None
    return _clip(1.0 - i_con / i_ref)


def pair_metrics(reference: EpisodeRecord, conflict: EpisodeRecord) -> dict[str, float | None]:
    return {
        "tar": tar(reference, conflict),
        "ts": ts(reference, conflict),
        "early20_ts": early20_ts(reference, conflict),
        "ams": ams(reference, conflict),
    }
