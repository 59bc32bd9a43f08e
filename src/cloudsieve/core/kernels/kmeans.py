"""Compiled kernels of K-means (numba; private: inputs are assumed valid).

:func:`pairwise_sum` (numpy's row summation), :func:`cluster_sums`, and one Lloyd
iteration with the bounds of :func:`cloudsieve.core.kmeans.lloyd`
(:func:`stale_bounds`, :func:`assign_pass`, :func:`apply_moves`); seeding: :mod:`.cluster`.

Floating-point operations follow numpy's order, so results are bit for bit the
same: squared distances summed over coordinates from 0, row sums pairwise,
per-cluster sums in index order (as ``np.bincount``). Per-point kernels take a
row range for threads (``nogil``); the result does not depend on the ranges.

These kernels compile in :func:`.centres.sqdist`; numba's cache checks only a
function's own file, so after editing :mod:`.centres` delete this package's ``__pycache__``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .centres import sqdist

__all__ = ["pairwise_sum", "cluster_sums", "cluster_max", "stale_bounds", "assign_pass", "apply_moves"]

_PW_BLOCK = 128  # numpy's PW_BLOCKSIZE


@njit(cache=True, nogil=True, _nrt=False)
def _pairwise_block(a, lo, n):
    """numpy's pairwise sum of a[lo:lo + n] for n <= 128 (its unrolled base case)."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, nogil=True)
def pairwise_sum(a, lo, n):
    """numpy's pairwise sum of a[lo:lo + n] (1-D float64), bit for bit.

    ``x.sum(axis=1)`` on a C-contiguous float64 array is ``0.0 +`` this per row.
    An explicit stack replaces numpy's recursion (numba's cache keeps recursive functions unreliably).
    """
    if n <= _PW_BLOCK:
        return _pairwise_block(a, lo, n)
    # post-order walk of numpy's recursion: (lo, n, visited) frames and a stack of partial sums
    flo = np.empty(128, dtype=np.int64)
    fn = np.empty(128, dtype=np.int64)
    fv = np.zeros(128, dtype=np.uint8)
    vals = np.empty(128)
    top = 0
    nv = 0
    flo[0], fn[0], fv[0] = lo, n, 0
    while top >= 0:
        m = fn[top]
        if m <= _PW_BLOCK:
            vals[nv] = _pairwise_block(a, flo[top], m)
            nv += 1
            top -= 1
        elif fv[top] == 0:
            fv[top] = 1
            m2 = m // 2
            m2 -= m2 % 8
            b = flo[top]
            flo[top + 1], fn[top + 1], fv[top + 1] = b + m2, m - m2, 0  # right, done second
            flo[top + 2], fn[top + 2], fv[top + 2] = b, m2, 0  # left, done first
            top += 2
        else:  # both halves done: left + right
            vals[nv - 2] = vals[nv - 2] + vals[nv - 1]
            nv -= 1
            top -= 1
    return vals[0]


@njit(cache=True, nogil=True, inline="always")
def _rowsum_sqdist(X, i, C, t, buf):
    """``((X[i] - C[t]) ** 2).sum()`` as numpy computes it for one row of a 2-D array."""
    p = X.shape[1]
    if p < 8:  # numpy: 0.0 + (-0.0 + s_0 + s_1 + ...), the same as the sum in order
        return sqdist(X, i, C, t)
    for j in range(p):
        diff = X[i, j] - C[t, j]
        buf[j] = diff * diff
    return 0.0 + pairwise_sum(buf, np.int64(0), p)


@njit(cache=True, nogil=True)
def cluster_sums(X, a, c):
    """Per-cluster sums S (c, p) and counts (c,) float64 of X by label a, in index order (as ``np.bincount``)."""
    n, p = X.shape
    S = np.zeros((c, p))
    cnt = np.zeros(c)
    for i in range(n):
        g = a[i]
        cnt[g] += 1.0
        for j in range(p):
            S[g, j] += X[i, j]
    return S, cnt


@njit(cache=True, nogil=True)
def cluster_max(a, v, out):
    """out[a[i]] = max(out[a[i]], v[i]) for every i (``np.maximum.at``)."""
    for i in range(len(a)):
        if v[i] > out[a[i]]:
            out[a[i]] = v[i]


@njit(cache=True, nogil=True)
def stale_bounds(a, L, R, cumD, cumM, T, near, s, e, umax):
    """Rows s..e-1: bounds brought to bounds over all centres before the lists are re-made (``lloyd``).

    With ub = L - R + cumD[a], lb = max(min(L - cumM[a], T[a] - ub), near[a] - ub):
    L = lb, R = lb - ub; umax[g] (zeros on entry) the largest ub of cluster g.
    """
    for i in range(s, e):
        g = a[i]
        ub = (L[i] - R[i]) + cumD[g]
        lb = min(L[i] - cumM[g], T[g] - ub)
        lb = max(lb, near[g] - ub)
        L[i] = lb
        R[i] = lb - ub
        if ub > umax[g]:
            umax[g] = ub


@njit(cache=True, nogil=True)
def assign_pass(X, a, L, R, Q, C, cumD, cumM, T, near, nb, s, e, na, umax, rows):
    """Rows s..e-1 of one Lloyd iteration with bounds (see ``lloyd``).

    A point with R > Q[a] keeps its label. Else with u its exact distance and
    low = max(min(L - cumM[a], T[a] - u), near[a] - u), it keeps its label if u < low.
    Else its nearest among its centre and nb[a] is found, exact when d1 < T[a] - u;
    a changed label is listed with na, an unsure one with na = -1 (a query over all
    centres); :func:`apply_moves` applies them. umax: this range's own array. Listed
    rows go, ascending, to rows[s:s + count]; returns (count, points reassigned among the lists).
    """
    K = nb.shape[1]
    buf = np.empty(X.shape[1])
    D = np.empty(K + 1)
    todo = 0
    count = 0
    for i in range(s, e):
        g = a[i]
        if R[i] > Q[g]:
            continue
        u = math.sqrt(_rowsum_sqdist(X, i, C, g, buf))
        low = max(min(L[i] - cumM[g], T[g] - u), near[g] - u)
        if u < low:
            L[i] = low + cumM[g]
            R[i] = ((low - u) + cumD[g]) + cumM[g]
            continue
        todo += 1
        D[0] = sqdist(X, i, C, g)
        k1 = 0
        for q in range(K):
            D[q + 1] = sqdist(X, i, C, nb[g, q])
            if D[q + 1] < D[k1]:
                k1 = q + 1
        second = np.inf
        for q in range(K + 1):
            if q != k1 and D[q] < second:
                second = D[q]
        d1 = math.sqrt(D[k1])
        far = T[g] - u
        if d1 < far:
            h = g if k1 == 0 else nb[g, k1 - 1]
            low = min(math.sqrt(second), far)
            L[i] = low + cumM[h]
            R[i] = ((low - d1) + cumD[h]) + cumM[h]
            v = d1 - cumD[h]
            if v > umax[h]:
                umax[h] = v
            if h != g:
                rows[s + count] = i
                na[i] = h
                count += 1
        else:
            rows[s + count] = i
            na[i] = -1
            count += 1
    return count, todo


@njit(cache=True, nogil=True)
def apply_moves(X, rows, a, na, d1o, lowo, L, R, cumD, cumM, umax, out, inn, cnt_out, cnt_in):
    """The listed rows (ascending) of :func:`assign_pass` take their labels, in order.

    Queried rows (d1o, lowo (len(rows),) at their position in ``rows``) get their
    bounds first; moved points are added to out / cnt_out and inn / cnt_in in
    index order (as ``np.bincount``). Returns the points that changed cluster.
    """
    p = X.shape[1]
    moved = 0
    for r in range(len(rows)):
        i = rows[r]
        old = a[i]
        g = na[i]
        if d1o[r] >= 0:  # queried
            cD = cumD[g]
            L[i] = lowo[r] + cumM[g]
            R[i] = ((lowo[r] - d1o[r]) + cD) + cumM[g]
            v = d1o[r] - cD
            if v > umax[g]:
                umax[g] = v
        if g != old:
            moved += 1
            cnt_out[old] += 1.0
            cnt_in[g] += 1.0
            for j in range(p):
                out[old, j] += X[i, j]
                inn[g, j] += X[i, j]
            a[i] = g
    return moved
