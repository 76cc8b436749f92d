"""Compiled batch kernels: TS, Early20 TS and AMS of many pairs at once; TAR's approach per rollout.

The rollouts of a chunk are packed into flat arrays (end-effector positions and actions as rows,
offsets per rollout; AMS reads the actions' first six columns); pairs are index pairs into them.
Each thread owns one DTW workspace for the whole chunk, so no cost matrix is allocated per pair.
"""

from __future__ import annotations

import numpy as np

from .dtw import MATRIX_MAX_CELLS, numba

INF = np.inf

if numba is not None:
    from numba import njit, prange

    from .dtw import dtw_lex, dtw_matrix

    @njit(cache=True, nogil=True, error_model="numpy")
    def _ts(eef, c0, cn, r0, rn, sigma, acc, start, seen, queue, stamp):  # pragma: no cover
        """TS between rows c0..c0+cn (conflict) and r0..r0+rn (reference) of ``eef``; nan if undefined."""
        if cn == 0 or rn == 0:
            return np.nan
        ax = np.empty(cn)
        ay = np.empty(cn)
        az = np.empty(cn)
        bx = np.empty(rn)
        by = np.empty(rn)
        bz = np.empty(rn)
        finite = True
        for t in range(cn):  # coordinates as separate arrays so that the DTW loop vectorises
            ax[t] = eef[c0 + t, 0]
            ay[t] = eef[c0 + t, 1]
            az[t] = eef[c0 + t, 2]
            finite = finite and np.isfinite(ax[t]) and np.isfinite(ay[t]) and np.isfinite(az[t])
        for t in range(rn):  # the reference reversed: both are read forwards along an anti-diagonal
            bx[t] = eef[r0 + rn - 1 - t, 0]
            by[t] = eef[r0 + rn - 1 - t, 1]
            bz[t] = eef[r0 + rn - 1 - t, 2]
            finite = finite and np.isfinite(bx[t]) and np.isfinite(by[t]) and np.isfinite(bz[t])
        if not finite:
            return np.nan
        if cn * rn <= seen.shape[0]:
            cost, cells = dtw_matrix(ax, ay, az, bx, by, bz, acc, start, seen, queue, stamp)
        else:
            cost, cells = dtw_lex(ax, ay, az, bx, by, bz)
        value = np.exp(-cost / (sigma * cells))
        return min(max(value, 0.0), 1.0)

    @njit(cache=True, nogil=True, error_model="numpy")
    def _intensity(act, lo, hi, gamma):  # pragma: no cover - compiled
        """I(tau) = mean_t ||a_t[:6] / gamma||_2 over rows lo..hi of ``act`` (rows of 6)."""
        total = 0.0
        for t in range(lo, hi):
            s = 0.0
            for j in range(6):
                v = act[t, j] / gamma[j]
                s += v * v
            total += np.sqrt(s)
        return total / (hi - lo)

    @njit(cache=True, nogil=True, error_model="numpy")
    def _ams(act, ref_lo, ref_hi, con_lo, con_hi, eps):  # pragma: no cover - compiled
        if ref_hi <= ref_lo or con_hi <= con_lo:
            return np.nan
        gamma = np.empty(6)  # from the REFERENCE actions only
        for j in range(6):
            s = 0.0
            for t in range(ref_lo, ref_hi):
                s += act[t, j] * act[t, j]
            gamma[j] = np.sqrt(max(s / (ref_hi - ref_lo), eps))
        i_ref = _intensity(act, ref_lo, ref_hi, gamma)
        i_con = _intensity(act, con_lo, con_hi, gamma)
        if not (np.isfinite(i_ref) and np.isfinite(i_con)) or i_ref <= eps:
            return np.nan
        return min(max(1.0 - i_con / i_ref, 0.0), 1.0)

    @njit(cache=True, parallel=True, error_model="numpy")
    def pair_kernel(eef, eoff, act, aoff, ref, con, sigma, early_points, eps, nthreads):  # pragma: no cover
        """TS, Early20 TS and AMS of each pair (``ref[p]``, ``con[p]`` index the packed rollouts)."""
        npairs = ref.shape[0]
        ts = np.empty(npairs)
        early = np.empty(npairs)
        ams = np.empty(npairs)
        max_cells = 0
        max_points = early_points * 2
        for p in range(npairs):
            cn = eoff[con[p] + 1] - eoff[con[p]]
            rn = eoff[ref[p] + 1] - eoff[ref[p]]
            if cn * rn <= MATRIX_MAX_CELLS:
                max_cells = max(max_cells, cn * rn)
                max_points = max(max_points, cn + rn)
        max_cells = max(max_cells, early_points * early_points)
        # one DTW workspace per thread, picked by thread id: pairs are handed out dynamically
        # (chunks set by the caller), so a thread slowed by other processes does not hold the rest
        acc = np.empty((nthreads, max_cells + 2 * max_points + 2))
        start = np.empty((nthreads, max_points), dtype=np.int64)
        seen = np.zeros((nthreads, max_cells), dtype=np.int32)
        queue = np.empty((nthreads, 2, max_cells), dtype=np.int32)
        for p in prange(npairs):
            w = numba.get_thread_id()
            r = ref[p]
            c = con[p]
            r0, rn = eoff[r], eoff[r + 1] - eoff[r]
            c0, cn = eoff[c], eoff[c + 1] - eoff[c]
            ts[p] = _ts(eef, c0, cn, r0, rn, sigma, acc[w], start[w], seen[w], queue[w], 2 * p + 1)
            early[p] = _ts(
                eef,
                c0,
                min(cn, early_points),
                r0,
                min(rn, early_points),
                sigma,
                acc[w],
                start[w],
                seen[w],
                queue[w],
                2 * p + 2,
            )
            ams[p] = _ams(act, aoff[r], aoff[r + 1], aoff[c], aoff[c + 1], eps)
        return ts, early, ams

    @njit(cache=True, parallel=True, error_model="numpy")
    def approach_kernel(eef, eoff, tgt, toff, k):  # pragma: no cover - compiled
        """A = max(d_0 - min_t d_t, 0) per rollout, d_t = min over its k targets of ||eef_t - obj_t||.

        ``tgt`` holds each rollout's (H+1) x k x 3 target positions as rows of 3 from ``toff``;
        nan where undefined (no state, no target, or a non-finite distance).
        """
        nroll = eoff.shape[0] - 1
        out = np.empty(nroll)
        for r in prange(nroll):
            lo, hi, kr = eoff[r], eoff[r + 1], k[r]
            if hi == lo or kr == 0:
                out[r] = np.nan
                continue
            d0 = np.nan
            dmin = INF
            ok = True
            for t in range(hi - lo):
                dt = INF
                for q in range(kr):
                    row = toff[r] + t * kr + q
                    ddx = eef[lo + t, 0] - tgt[row, 0]
                    ddy = eef[lo + t, 1] - tgt[row, 1]
                    ddz = eef[lo + t, 2] - tgt[row, 2]
                    dist = np.sqrt(ddx * ddx + ddy * ddy + ddz * ddz)
                    ok = ok and np.isfinite(dist)
                    dt = min(dt, dist)
                if t == 0:
                    d0 = dt
                dmin = min(dmin, dt)
            out[r] = max(d0 - dmin, 0.0) if ok else np.nan
        return out


def available() -> bool:
    """Whether the compiled fast path can run (numba importable)."""
    return numba is not None


def threads() -> int:
    """Threads the kernels may run on: the pool's size, so that every thread id has a workspace."""
    return numba.config.NUMBA_NUM_THREADS if numba is not None else 1


def dynamic_schedule(pairs_per_task: int = 4):
    """Hand out pairs to the kernel's threads a few at a time instead of in equal shares."""
    return numba.parallel_chunksize(pairs_per_task)
