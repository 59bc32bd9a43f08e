"""Compiled kernels of fuzzy C-means over the nearest centres (numba; private: inputs are assumed valid).

:func:`update_rows` (one membership update of a row range, with queries via
:func:`.centres.knn_row`), :func:`finish_rows` (after an outside query),
:func:`block_sums`, :func:`nearest_first`, :func:`max_change`.

As in :mod:`.kmeans`, floating-point operations follow numpy's order, bit for bit
(for m != 2 the powers are libm's ``pow``, which may differ from numpy's in the last bit).
These kernels compile in functions of :mod:`.centres` and :mod:`.kmeans`; after
editing those, delete this package's ``__pycache__`` (numba's cache checks one file).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .centres import knn_row, sqdist
from .kmeans import pairwise_sum

__all__ = ["memberships", "update_rows", "finish_rows", "block_sums", "nearest_first", "max_change"]


@njit(cache=True, nogil=True)
def memberships(d2, e, u, r):
    """u_l = 1 / sum_q (d2_l / d2_q)^e over squared distances d2 (L,), into u (L,); r (L,) scratch.

    Computed as r = (min d2 / d2)^e, u = r / (0.0 + pairwise sum of r); zero distances share 1 equally.
    """
    L = len(d2)
    dmin = d2[0]
    for q in range(1, L):
        if d2[q] < dmin:
            dmin = d2[q]
    if dmin == 0.0:
        z = 0
        for q in range(L):
            if d2[q] == 0.0:
                z += 1
        for q in range(L):
            u[q] = (1.0 if d2[q] == 0.0 else 0.0) / z
        return
    for q in range(L):
        r[q] = dmin / d2[q]
        if e != 1.0:
            r[q] = r[q] ** e
    s = 0.0 + pairwise_sum(r, np.int64(0), L)
    for q in range(L):
        u[q] = r[q] / s


@njit(cache=True, nogil=True, _nrt=False)
def _row_change(old_i, old_u, new_i, new_u):
    """max |U1 - U0| over one row of the full n x c matrices: U0 nonzero at old_i, U1 at new_i."""
    L0 = len(old_i)
    L1 = len(new_i)
    best = 0.0
    for a in range(L1):
        v = new_u[a]
        for b in range(L0):
            if old_i[b] == new_i[a]:
                v = new_u[a] - old_u[b]
                break
        v = abs(v)
        if v > best:
            best = v
    for b in range(L0):
        found = False
        for a in range(L1):
            if old_i[b] == new_i[a]:
                found = True
                break
        if not found and abs(old_u[b]) > best:
            best = abs(old_u[b])
    return best


@njit(cache=True, nogil=True)
def max_change(idx0, U0, idx1, U1):
    """max |U1 - U0| over the full n x c matrices from kept entries (n, L0), (n, L1); absent entries are 0."""
    best = 0.0
    for i in range(len(idx0)):
        v = _row_change(idx0[i], U0[i], idx1[i], U1[i])
        if v > best:
            best = v
    return best


@njit(cache=True, nogil=True, inline="always")
def _finish(i, X, Ib, D2, idx, U, hard, have, e, ub, r):
    """End of row i's update with new sorted centres Ib and D2: memberships, their change (returned), hard label."""
    L = len(Ib)
    memberships(D2, e, ub, r)
    ch = 0.0
    same = have
    if have:
        for q in range(L):
            if Ib[q] != idx[i, q]:
                same = False
                break
        if same:
            for q in range(L):
                v = abs(ub[q] - U[i, q])
                if v > ch:
                    ch = v
        else:
            ch = _row_change(idx[i], U[i], Ib, ub)
    relabel = 0
    if len(hard):
        best = 0
        for q in range(1, L):
            if ub[q] > ub[best]:
                best = q
        hb = Ib[best]
        if hb != hard[i]:
            relabel = 1
        hard[i] = hb
    for q in range(L):
        U[i, q] = ub[q]
    if not same:
        for q in range(L):
            idx[i, q] = Ib[q]
    return ch, relabel


@njit(cache=True, nogil=True, _nrt=False)
def _sort_small(keys, vals, n):
    """Stable insertion sort of keys[:n] carrying vals[:n] (n is small)."""
    for a in range(1, n):
        k = keys[a]
        v = vals[a]
        b = a
        while b > 0 and keys[b - 1] > k:
            keys[b] = keys[b - 1]
            vals[b] = vals[b - 1]
            b -= 1
        keys[b] = k
        vals[b] = v


@njit(cache=True, nogil=True)
def update_rows(X, C, idx, ring, U, reach, hard, have, e, s, e_row, K, grid, lists, flag):
    """One membership update of rows s..e_row-1 (see ``cloudsieve.core.fcm._fcm``).

    Without ``have`` (first update) every row is queried. Otherwise distances to the
    L centres and the ring are recomputed, closer ring centres swap in, and the row is
    queried again unless its farthest distance is below reach[i]^2; tied queries
    (flag[i] = 1) are left to :func:`finish_rows`. ``grid``, ``lists``: the tuples of
    :mod:`.centres`; ``hard`` (n,) or (0,): hard labels (length 0: not tracked).
    Returns (largest membership change, hard labels changed).
    """
    L = idx.shape[1]
    E = ring.shape[1]
    n_c = C.shape[0]
    extra = L < n_c
    Ib = np.empty(L, dtype=np.int64)
    D2 = np.empty(L)
    cand = np.empty(L + E, dtype=np.int64)
    dc = np.empty(L + E)
    ub = np.empty(L)
    r = np.empty(L)
    qd = np.empty(K)
    qi = np.empty(K, dtype=np.int64)
    ch = 0.0
    relabelled = 0
    for i in range(s, e_row):
        flag[i] = 0
        redo = not have
        if have:
            top = -np.inf
            for q in range(L):
                Ib[q] = idx[i, q]
                D2[q] = sqdist(X, i, C, Ib[q])
                if D2[q] > top:
                    top = D2[q]
            if extra:
                qmin = np.inf
                for q in range(E):
                    cand[L + q] = ring[i, q]
                    dc[L + q] = sqdist(X, i, C, ring[i, q])
                    if dc[L + q] < qmin:
                        qmin = dc[L + q]
                if qmin < top:  # a ring centre came closer than a member: the L nearest of both
                    for q in range(L):
                        cand[q] = Ib[q]
                        dc[q] = D2[q]
                    _sort_small(dc, cand, L + E)
                    for q in range(L):
                        Ib[q] = cand[q]
                        D2[q] = dc[q]
                    _sort_small(Ib, D2, L)  # by index
                    for q in range(E):
                        ring[i, q] = cand[L + q]
                    top = dc[L - 1]
                rb = reach[i]
                redo = not (top < (rb * rb if rb > 0 else -1.0))
        if redo:
            if knn_row(X, i, grid, lists, K, qd, qi):
                flag[i] = 1
                continue
            if K > L + E:
                reach[i] = math.sqrt(qd[L + E])
            for q in range(L):
                Ib[q] = qi[q]
            _sort_small(Ib, D2, L)  # by index
            for q in range(E):
                ring[i, q] = qi[L + q]
            for q in range(L):
                D2[q] = sqdist(X, i, C, Ib[q])
        c1, c2 = _finish(i, X, Ib, D2, idx, U, hard, have, e, ub, r)
        if c1 > ch:
            ch = c1
        relabelled += c2
    return ch, relabelled


@njit(cache=True, nogil=True)
def finish_rows(X, C, rows, qd, qi, idx, ring, U, reach, hard, have, e):
    """Rows ``rows`` after their outside query (qd, qi) (m, K), as the end of :func:`update_rows`. Returns (change, labels changed)."""
    L = idx.shape[1]
    E = ring.shape[1]
    K = qd.shape[1]
    Ib = np.empty(L, dtype=np.int64)
    D2 = np.empty(L)
    ub = np.empty(L)
    r = np.empty(L)
    ch = 0.0
    relabelled = 0
    for t in range(len(rows)):
        i = rows[t]
        if K > L + E:
            reach[i] = qd[t, L + E]
        for q in range(L):
            Ib[q] = qi[t, q]
        _sort_small(Ib, D2, L)  # by index
        for q in range(E):
            ring[i, q] = qi[t, L + q]
        for q in range(L):
            D2[q] = sqdist(X, i, C, Ib[q])
        c1, c2 = _finish(i, X, Ib, D2, idx, U, hard, have, e, ub, r)
        if c1 > ch:
            ch = c1
        relabelled += c2
    return ch, relabelled


@njit(cache=True, nogil=True)
def block_sums(X, idx, U, m, s, e, c):
    """Sums of rows s..e-1: den (c,) of W = U^m and num (c, p) of W x, in row-major order from 0.0 (``np.bincount``)."""
    p = X.shape[1]
    L = idx.shape[1]
    num = np.zeros((c, p))
    den = np.zeros(c)
    for i in range(s, e):
        for q in range(L):
            u = U[i, q]
            w = u * u if m == 2.0 else u ** m
            g = idx[i, q]
            den[g] += w
            for j in range(p):
                num[g, j] += w * X[i, j]
    return num, den


@njit(cache=True, nogil=True)
def nearest_first(X, C, idx, U, s, e):
    """Rows s..e-1: idx[i] and U[i] ordered by distance to C[idx[i]] (stable)."""
    L = idx.shape[1]
    d = np.empty(L)
    o = np.empty(L, dtype=np.int64)
    ti = np.empty(L, dtype=np.int64)
    tu = np.empty(L)
    for i in range(s, e):
        for q in range(L):
            d[q] = math.sqrt(sqdist(X, i, C, idx[i, q]))
            o[q] = q
        _sort_small(d, o, L)
        for q in range(L):
            ti[q] = idx[i, o[q]]
            tu[q] = U[i, o[q]]
        for q in range(L):
            idx[i, q] = ti[q]
            U[i, q] = tu[q]
