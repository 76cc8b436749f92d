"""Compiled DTW between end-effector paths: accumulated cost and L, the cells on the optimal path.

Definition (the same in ``plain.dtw``): local cost c(i, j) = ||a_i - b_j||, computed as
sqrt((dx*dx + dy*dy) + dz*dz); D(0, 0) = c(0, 0); D(i, j) = c(i, j) + min(D(i-1, j), D(i, j-1),
D(i-1, j-1)) over the predecessors that exist; DTW = D(n-1, m-1).

Tie-breaking rule for L: among the warping paths of minimum accumulated cost, L is the number of
cells of the SHORTEST one. A predecessor is on an optimal path when its accumulated cost equals
the minimum of the cell's predecessors (float64 equality of the values the recurrence computes),
so L is the shortest (0,0) -> (n-1,m-1) path through such "tight" links. The rule is global (not a
greedy back-trace preference such as "diagonal first"), it does not depend on the order in which
predecessors are listed, and DTW(P, Q) == DTW(Q, P) exactly; every implementation here returns
the same bits.

Two kernels compute it. Both walk anti-diagonals (k = i + j): the cells of one anti-diagonal do
not depend on each other, so the inner loop vectorises, where a row-by-row loop waits on its
D(i, j-1) -> D(i, j) chain.
- ``dtw_matrix`` keeps the accumulated costs (about 8 bytes per cell, in a per-thread workspace
  reused from pair to pair) and finds L afterwards by a breadth-first search backwards over the
  tight links, which visits about n + m cells unless costs tie. It is the fast one.
- ``dtw_lex`` keeps only three anti-diagonals of (cost, cells) pairs, taking the lexicographic
  minimum at every cell: O(n + m) memory, used when n * m exceeds the workspace cap.
"""

from __future__ import annotations

import numpy as np

try:  # numba ships with the simulator stack; without it the plain implementation is used
    import numba
    from numba import njit
except ImportError:  # pragma: no cover - exercised only on installs without numba
    numba = None

INF = np.inf
#: Largest n * m handled by ``dtw_matrix`` (20 bytes of workspace per cell and thread).
MATRIX_MAX_CELLS = 4_000_000

if numba is not None:
    _U = numba.uint64  # unsigned indices: no negative-index wraparound check, so the loop vectorises

    @njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
    def dtw_lex(ax, ay, az, bxr, byr, bzr):  # pragma: no cover - compiled
        """(cost, L) with O(n + m) memory. ``a`` as coordinate arrays, ``b`` REVERSED
        (``bxr[t] = b[m-1-t, 0]``) so both are read forwards along an anti-diagonal."""
        n = ax.shape[0]
        m = bxr.shape[0]
        if n == 0 or m == 0:
            return np.nan, 0
        # One anti-diagonal per buffer, cell (i, k - i) at slot i + 1; slot 0 stays inf so that
        # i - 1 = -1 reads "no predecessor". d1/l1: diagonal k-1, d2/l2: k-2, d0/l0: k.
        d0 = np.full(n + 2, INF)
        d1 = np.full(n + 2, INF)
        d2 = np.full(n + 2, INF)
        l0 = np.full(n + 2, INF)
        l1 = np.full(n + 2, INF)
        l2 = np.full(n + 2, INF)
        dx = ax[0] - bxr[m - 1]
        dy = ay[0] - byr[m - 1]
        dz = az[0] - bzr[m - 1]
        d1[1] = np.sqrt(dx * dx + dy * dy + dz * dz)
        l1[1] = 1.0
        one = _U(1)
        for k in range(1, n + m - 1):
            lo = max(0, k - m + 1)
            hi = min(n - 1, k)
            ulo = _U(lo)
            off = _U(m - 1 - k + lo)  # reversed b index of j = k - i
            for q in range(_U(hi - lo + 1)):
                i = ulo + q
                t = off + q
                dx = ax[i] - bxr[t]
                dy = ay[i] - byr[t]
                dz = az[i] - bzr[t]
                c = np.sqrt(dx * dx + dy * dy + dz * dz)
                up = d1[i]  # (i-1, j)
                left = d1[i + one]  # (i, j-1)
                diag = d2[i]  # (i-1, j-1)
                lup = l1[i]
                lleft = l1[i + one]
                ldiag = l2[i]
                best = up if up < left else left
                best = best if best < diag else diag
                lup = lup if up == best else INF  # fewest cells among the tight predecessors
                lleft = lleft if left == best else INF
                ldiag = ldiag if diag == best else INF
                cells = lup if lup < lleft else lleft
                cells = cells if cells < ldiag else ldiag
                d0[i + one] = c + best
                l0[i + one] = cells + 1.0
            d0[hi + 2] = INF  # the next two diagonals may read one slot past this one's end
            l0[hi + 2] = INF
            d0, d1, d2 = d2, d0, d1
            l0, l1, l2 = l2, l0, l1
        return d1[n], int(l1[n])

    @njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
    def _forward(ax, ay, az, bxr, byr, bzr, acc, start):  # pragma: no cover - compiled
        """Fill ``acc`` with every accumulated cost, anti-diagonal by anti-diagonal.

        Diagonal k is stored from ``start[k]`` as [inf, cells lo_k..hi_k, inf]; the inf borders
        stand for the predecessors outside the matrix. ``acc[0:2]`` is an all-inf diagonal -1.
        """
        n = ax.shape[0]
        m = bxr.shape[0]
        nd = n + m - 1
        pos = 2
        for k in range(nd):
            start[k] = pos
            pos += min(n - 1, k) - max(0, k - m + 1) + 3
        acc[0] = INF
        acc[1] = INF
        s0 = start[0]
        dx = ax[0] - bxr[m - 1]
        dy = ay[0] - byr[m - 1]
        dz = az[0] - bzr[m - 1]
        acc[s0] = INF
        acc[s0 + 1] = np.sqrt(dx * dx + dy * dy + dz * dz)
        acc[s0 + 2] = INF
        one = _U(1)
        for k in range(1, nd):
            lo = max(0, k - m + 1)
            hi = min(n - 1, k)
            s = start[k]
            acc[s] = INF
            acc[s + hi - lo + 2] = INF
            lo1 = max(0, k - m)
            base_up = _U(start[k - 1] + lo - lo1)  # (i-1, j) at base_up + q, (i, j-1) one further
            base_diag = _U(start[k - 2] + lo - max(0, k - m - 1)) if k >= 2 else _U(lo)
            base_out = _U(s + 1)
            ulo = _U(lo)
            off = _U(m - 1 - k + lo)
            for q in range(_U(hi - lo + 1)):
                i = ulo + q
                t = off + q
                dx = ax[i] - bxr[t]
                dy = ay[i] - byr[t]
                dz = az[i] - bzr[t]
                c = np.sqrt(dx * dx + dy * dy + dz * dz)
                up = acc[base_up + q]
                left = acc[base_up + q + one]
                diag = acc[base_diag + q]
                best = up if up < left else left
                best = best if best < diag else diag
                acc[base_out + q] = c + best

    @njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
    def _at(acc, start, m, i, j):  # pragma: no cover - compiled
        k = i + j
        return acc[start[k] + 1 + i - max(0, k - m + 1)]

    @njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
    def dtw_matrix(ax, ay, az, bxr, byr, bzr, acc, start, seen, queue, stamp):  # pragma: no cover
        """(cost, L) using the workspace ``acc`` (>= n*m + 2(n+m) + 2 floats), ``start`` (>= n+m),
        ``seen`` (>= n*m int32, not holding ``stamp`` yet) and ``queue`` (2 x >= n*m int32)."""
        n = ax.shape[0]
        m = bxr.shape[0]
        if n == 0 or m == 0:
            return np.nan, 0
        _forward(ax, ay, az, bxr, byr, bzr, acc, start)
        cost = _at(acc, start, m, n - 1, m - 1)
        # Breadth-first search backwards from the last cell over tight links: the depth at which
        # (0, 0) is first reached is the fewest cells of any minimum-cost path. The queue holds
        # (i, j) in two rows; ``seen`` marks cells by i * m + j with this call's stamp.
        qi = queue[0]
        qj = queue[1]
        qi[0] = n - 1
        qj[0] = m - 1
        seen[(n - 1) * m + m - 1] = stamp
        head, tail, level_end, depth = 0, 1, 1, 1
        while head < tail:  # always reaches (0, 0) for finite costs; the bound is a safeguard
            if head == level_end:
                depth += 1
                level_end = tail
            i = qi[head]
            j = qj[head]
            head += 1
            if i == 0 and j == 0:
                return cost, depth
            up = _at(acc, start, m, i - 1, j) if i > 0 else INF
            left = _at(acc, start, m, i, j - 1) if j > 0 else INF
            diag = _at(acc, start, m, i - 1, j - 1) if i > 0 and j > 0 else INF
            best = min(up, left, diag)
            cell = i * m + j
            if i > 0 and up == best and seen[cell - m] != stamp:
                seen[cell - m] = stamp
                qi[tail] = i - 1
                qj[tail] = j
                tail += 1
            if j > 0 and left == best and seen[cell - 1] != stamp:
                seen[cell - 1] = stamp
                qi[tail] = i
                qj[tail] = j - 1
                tail += 1
            if i > 0 and j > 0 and diag == best and seen[cell - m - 1] != stamp:
                seen[cell - m - 1] = stamp
                qi[tail] = i - 1
                qj[tail] = j - 1
                tail += 1
        return np.nan, 0


def workspace(max_cells: int, max_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Buffers for ``dtw_matrix`` up to n*m = max_cells and n+m = max_points."""
    return (
        np.empty(max_cells + 2 * max_points + 2),
        np.empty(max_points, dtype=np.int64),
        np.zeros(max_cells, dtype=np.int32),
        np.empty((2, max_cells), dtype=np.int32),
    )
