"""Compiled kernels of the k-NN lists kept between rounds (numba; private, inputs assumed valid).

Each row keeps its k + 1 + e nearest in ``nb`` (n, W), nearest first, padded with
n; ``kk`` its k, ``rk``, ``rk1``, ``r1`` its r_k, r_(k+1), r_1 (+inf without a list);
other arrays as :mod:`.rounds`. Removed rows leave the lists (:func:`repack_lists`);
short lists are remade (:func:`refresh_lists`). Distances are summed as cKDTree's,
bit for bit; a new list is the tree's whenever that is unique, else the caller asks the tree.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, _nrt=False)
def _dist(P, a, b):
    """|P[a] - P[b]|, summed coordinate by coordinate from the first (the k-d tree's order)."""
    s = 0.0
    for j in range(P.shape[1]):
        d = P[a, j] - P[b, j]
        s += d * d
    return math.sqrt(s)


@njit(cache=True, nogil=True, _nrt=False)
def _nearest(P, nb, kk, x, n):
    """r_1(x): the distance to the first entry of x's list; inf when x has no list."""
    if kk[x] <= 0 or nb.shape[1] == 0:
        return np.inf
    y = nb[x, 0]
    if y < 0 or y >= n:
        return np.inf
    return _dist(P, x, y)


@njit(cache=True, nogil=True)
def spacings(P, nb, kk):
    """r_1 of every row (n,) float64: distance to its nearest listed neighbour, inf without a list."""
    n = len(kk)
    r1 = np.empty(n)
    for x in range(n):
        r1[x] = _nearest(P, nb, kk, x, n)
    return r1


@njit(cache=True, nogil=True)
def store_lists(rows, k, rk_rows, rk1_rows, lists, P, kk, rk, rk1, r1, nb):
    """Write the k-NN query results of ``rows``: kk = k, r_k, r_(k+1), the lists (padded with n), r_1."""
    n = len(kk)
    W = nb.shape[1]
    w = lists.shape[1]
    for i in range(len(rows)):
        r = rows[i]
        kk[r] = k
        rk[r] = rk_rows[i]
        rk1[r] = rk1_rows[i]
        for j in range(w):
            nb[r, j] = lists[i, j]
        for j in range(w, W):
            nb[r, j] = n
        r1[r] = _nearest(P, nb, kk, r, n)


@njit(cache=True, nogil=True)
def repack_lists(P, ginv, kk, rk, rk1, r1, nb, part, k_new, removed, a, b):
    """Drop ``removed`` rows ((n + 1,) bool) from the lists of rows a to b - 1 of the ``part`` clusters.

    A list that lost entries or whose cluster's k became k' = ``k_new`` is packed; if it
    keeps k' + 1 rows they are still the nearest, giving kk, r_k, r_(k+1), r1. Returns
    the other rows, ascending: they need a new query.
    """
    n = len(kk)
    W = nb.shape[1]
    short = np.empty(b - a, dtype=np.int64)
    ns = 0
    for row in range(a, b):
        if kk[row] <= 0 or not part[ginv[row]]:
            continue
        kn = k_new[ginv[row]]
        first = nb[row, 0]
        cnt = 0
        lost = 0
        end = W
        for j in range(W):  # pack in place (the entries come first, unchanged when none was removed)
            x = nb[row, j]
            if x >= n:
                end = j
                break
            if removed[x]:
                lost += 1
            else:
                nb[row, cnt] = x
                cnt += 1
        if lost == 0 and kk[row] == kn:
            continue
        for j in range(cnt, end):
            nb[row, j] = n
        if cnt >= kn + 1:
            kk[row] = kn
            rk[row] = _dist(P, row, nb[row, kn - 1])
            rk1[row] = _dist(P, row, nb[row, kn])
            if nb[row, 0] != first:
                r1[row] = _dist(P, row, nb[row, 0])
        else:
            short[ns] = row
            ns += 1
    return short[:ns].copy()


@njit(cache=True, nogil=True)
def refresh_lists(P, ginv, starts, alive, dup, q, kcl, extra, width):
    """New lists for rows ``q`` (ascending) among the alive distinct rows of their cluster, by brute force.

    Row y of cluster j gets k = kcl[j] and L = k + 1 + min(extra, m - k - 2) nearest,
    as :func:`cloudsieve.core.knn.knn_query`'s tree would (same sums). Returns lists
    (len(q), width) padded with n, kq, rk, rk1, r1 and status (int8): 0 done, 1 a tie
    (ask the tree), 2 a zero distance (the cluster holds copies).
    """
    n = len(ginv)
    p = P.shape[1]
    nq = len(q)
    lists = np.full((nq, width), n, dtype=np.int64)
    kq = np.zeros(nq, dtype=np.int64)
    rk = np.zeros(nq)
    rk1 = np.zeros(nq)
    r1 = np.zeros(nq)
    status = np.zeros(nq, dtype=np.int8)
    M = 1
    for j in range(len(starts) - 1):
        M = max(M, starts[j + 1] - starts[j])
    idx = np.empty(M, dtype=np.int64)
    cols = np.empty((p, M))  # the cluster's alive distinct points, one coordinate a row
    sq = np.empty(M)
    cs = np.empty(M)
    ci = np.empty(M, dtype=np.int64)
    ipos = np.zeros(M, dtype=np.int64)  # position in the buffer of each row of the cluster
    bs = np.empty(width + 2)  # the L + 1 smallest squared distances, ascending
    bi = np.empty(width + 2, dtype=np.int64)
    t = np.inf
    i = 0
    while i < nq:
        j = ginv[q[i]]
        m = 0
        t = np.inf
        for r in range(starts[j], starts[j + 1]):
            if alive[r] and not dup[r]:
                ipos[r - starts[j]] = m
                idx[m] = r
                for d in range(p):
                    cols[d, m] = P[r, d]
                m += 1
        k = kcl[j]
        e = min(extra, max(m - k - 2, 0))
        L = k + 1 + e
        while i < nq and ginv[q[i]] == j:
            y = q[i]
            # squared distances, summed coordinate by coordinate as the tree does (vectorised)
            c0 = P[y, 0]
            for a in range(m):
                dd = c0 - cols[0, a]
                sq[a] = dd * dd
            for d in range(1, p):
                cd = P[y, d]
                for a in range(m):
                    dd = cd - cols[d, a]
                    sq[a] += dd * dd
            # the L + 1 smallest (itself excluded): a threshold t with L + 1 to L + 5 values <= t, then ranked
            sp = ipos[y - starts[j]]
            sq[sp] = np.inf
            need = min(L + 1, m - 1)
            if need <= 0:
                nbuf = 0
            else:
                if not (0.0 < t < np.inf):
                    tot = 0.0
                    for a in range(m):
                        if sq[a] < np.inf:
                            tot += sq[a]
                    t = tot / m * (need + 1) / m * 2.0
                lo = 0.0  # bisection of t: count(<= lo) < need, count(<= hi) > need + 4
                hi = np.inf
                good = np.inf  # a t known to hold >= need values
                for _ in range(64):
                    cnt = 0
                    for a in range(m):
                        cnt += (sq[a] <= t) & (a != sp)
                    if cnt >= need:
                        good = t
                        if cnt <= need + 4:
                            break
                        hi = t
                        t2 = (lo + t) / 2
                    else:
                        lo = t
                        t2 = t * 2.0 if hi == np.inf else (t + hi) / 2
                    if not (lo < t2 < hi):  # no value between (ties, or t = 0): settle
                        break
                    t = t2
                t = good
                cnt = 0
                for a in range(m):
                    v = sq[a]
                    cs[cnt] = v
                    ci[cnt] = a
                    cnt += (v <= t) & (a != sp)
                for x in range(cnt):  # rank (ties by position) without branches
                    v = cs[x]
                    rank = 0
                    for z in range(cnt):
                        w = cs[z]
                        rank += (w < v) | ((w == v) & (z < x))
                    if rank <= L:
                        bs[rank] = v
                        bi[rank] = idx[ci[x]]
                nbuf = min(cnt, L + 1)
                t = bs[need - 1] * 1.1
            st = 0
            if nbuf == 0 or bs[0] == 0.0:
                st = 2
            else:
                for b in range(1, min(nbuf, L + 1)):
                    if bs[b] == bs[b - 1]:
                        st = 1
                        break
            status[i] = st
            if st == 0:
                kq[i] = k
                for b in range(L):
                    lists[i, b] = bi[b]
                rk[i] = math.sqrt(bs[k - 1])
                rk1[i] = math.sqrt(bs[k])
                r1[i] = math.sqrt(bs[0])
            i += 1
    return lists, kq, rk, rk1, r1, status


@njit(cache=True, nogil=True)
def store_refreshed(q, status, lists, kq, rkq, rk1q, r1q, kk, rk, rk1, r1, nb):
    """Write the lists of :func:`refresh_lists` with status 0 into the state."""
    W = nb.shape[1]
    for i in range(len(q)):
        if status[i] != 0:
            continue
        r = q[i]
        kk[r] = kq[i]
        rk[r] = rkq[i]
        rk1[r] = rk1q[i]
        r1[r] = r1q[i]
        for j in range(W):
            nb[r, j] = lists[i, j]
