"""Compiled kernels of the ``iterative`` and ``coverage`` rounds (numba; private, inputs assumed valid).

The caller (:mod:`cloudsieve.core.rounds`) keeps the state of the rounds in
flat arrays over the n points (its own order, "rows"):

- ``nb`` (n, K) int64: the neighbour list of each row, nearest first; an
  entry outside [0, n) (-1 or n) is no neighbour, and only the first
  ``kk[row]`` columns count (``kk`` (n,) int64; 0: the row has no list);
- ``val`` (n,) float64 the scores, ``alive`` (n,) bool, ``ginv`` (n,) int64
  the cluster of each row (0..c-1), ``dup`` (n,) bool the exact copies.

Exactness: every floating-point value is computed with the operations, and
sums in the order, of the numpy code it replaced (distances as
``((d0 * d0) + d1 * d1) + d2 * d2`` then ``sqrt``, as the k-d tree does;
cluster sums in ascending row order, as ``np.bincount``), so the scores and
kept sets are the same bit for bit. ``log``, ``exp`` and ``log1p`` are left
to numpy by the caller: numba's differ from numpy's SIMD ones in the last bit.
No function here allocates per point in a Python loop or uses threads, so the
results never depend on a thread count.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _dist(P, a, b):
    """|P[a] - P[b]|, summed coordinate by coordinate from the first (the k-d tree's order)."""
    s = 0.0
    for j in range(P.shape[1]):
        d = P[a, j] - P[b, j]
        s += d * d
    return math.sqrt(s)


@njit(cache=True, nogil=True)
def candidates(alive, val, threshold, any_finite):
    """The alive rows with val <= threshold (``any_finite``: with a finite val), ascending, and their val.

    Returns
    -------
    pool : ndarray of shape (m,), int64
    keys : ndarray of shape (m,), float64
    """
    n = len(val)
    pool = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if alive[i]:
            v = val[i]
            if (np.isfinite(v) if any_finite else v <= threshold):
                pool[m] = i
                m += 1
    pool = pool[:m]
    keys = np.empty(m)
    for i in range(m):
        keys[i] = val[pool[i]]
    return pool, keys


@njit(cache=True, nogil=True)
def break_ties(cand, keys, tie):
    """Sort, in place, each run of equal ``keys`` of ``cand`` (sorted by ``keys``, aligned with it) by ``tie``.

    With unique ``tie`` ids the result is the lexicographic order (val, tie),
    whatever order the sort left the equal values in.
    """
    m = len(cand)
    i = 0
    while i < m:
        j = i + 1
        v = keys[i]
        while j < m and keys[j] == v:
            j += 1
        if j - i > 1:
            seg = cand[i:j].copy()
            t = np.empty(j - i, dtype=np.int64)
            for a in range(j - i):
                t[a] = tie[seg[a]]
            o = np.argsort(t)
            for a in range(j - i):
                cand[i + a] = seg[o[a]]
        i = j


@njit(cache=True, nogil=True)
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
def spacings_at(P, nb, kk, rows, r1):
    """r1[rows] = r_1 of those rows (see :func:`spacings`)."""
    n = len(kk)
    for x in rows:
        r1[x] = _nearest(P, nb, kk, x, n)


_HALF_MAX = np.finfo(np.float64).max / 2


@njit(cache=True, nogil=True)
def _is_covered(nb, kk, r1, y, coverage, vals):
    """r_1(y) <= coverage * (median of r_1 over y's listed neighbours); False without neighbours.

    ``r1`` (n,) holds r_1 of every row, +inf for a row without a list (kk <= 0),
    as :func:`spacings` gives it. The median of an even count is the mean of
    the two middle values, as ``np.nanmedian``. With 0 < coverage < inf, c v
    is monotone in v, so the values v with r_1(y) <= c v are the upper part of
    the sorted values: counting them decides, except when the median is the
    mean of the largest value below and the smallest above (both known from
    the same pass), or when a sum could overflow; then (and for other
    coverages) the values are sorted. ``vals`` is scratch space of length >= K.
    """
    n = len(kk)
    if kk[y] <= 0 or nb.shape[1] == 0 or nb[y, 0] < 0 or nb[y, 0] >= n:
        return False
    r = r1[y]
    K = min(kk[y], nb.shape[1])
    if 0.0 < coverage < np.inf:
        cnt = 0
        s = 0  # values v with r <= c v
        lo_above = np.inf  # smallest of them
        hi_below = -np.inf  # largest of the others
        for j in range(K):
            x = nb[y, j]
            if 0 <= x < n:
                v = r1[x]
                cnt += 1
                up = r <= coverage * v  # no branch on it: it is a coin toss
                s += up
                lo_above = min(lo_above, v if up else np.inf)
                hi_below = max(hi_below, -np.inf if up else v)
        if cnt == 0:
            return False
        a = (cnt - 1) // 2  # the median is (v_a + v_b) / 2 of the sorted values
        b = cnt // 2
        first = cnt - s  # sorted position of the first value with r <= c v
        if first <= a:  # r <= c v_a <= c median
            return True
        if first > b and hi_below <= _HALF_MAX:  # r > c v_b >= c median (v_a + v_b does not overflow)
            return False
        if first == b and a < b:  # v_a, v_b: the largest below, the smallest above
            return r <= coverage * ((hi_below + lo_above) / 2)
    cnt = 0
    for j in range(K):
        x = nb[y, j]
        if 0 <= x < n:
            v = r1[x]
            a = cnt  # insertion sort: lists are short (k + 1 + spares)
            while a > 0 and vals[a - 1] > v:
                vals[a] = vals[a - 1]
                a -= 1
            vals[a] = v
            cnt += 1
    if cnt == 0:
        return False
    med = (vals[(cnt - 1) // 2] + vals[cnt // 2]) / 2
    return r <= coverage * med


@njit(cache=True, nogil=True)
def covered_mask(P, nb, kk, cand, coverage):
    """The coverage test of each candidate (bool (len(cand),)); see :func:`_is_covered`."""
    r1 = spacings(P, nb, kk)
    vals = np.empty(max(nb.shape[1], 1))
    ok = np.zeros(len(cand), dtype=np.bool_)
    for i in range(len(cand)):
        ok[i] = _is_covered(nb, kk, r1, cand[i], coverage, vals)
    return ok


@njit(cache=True, nogil=True)
def covered_rows(nb, kk, r1, coverage):
    """The coverage test of every row (bool (n,)), in row order (a cluster's rows are close in memory).

    ``r1`` (n,): the rows' r_1, +inf where kk <= 0 (:func:`spacings`).
    """
    n = len(kk)
    vals = np.empty(max(nb.shape[1], 1))
    ok = np.zeros(n, dtype=np.bool_)
    for y in range(n):
        if kk[y] > 0:
            ok[y] = _is_covered(nb, kk, r1, y, coverage, vals)
    return ok


@njit(cache=True, nogil=True)
def select_round(cand, nb, kk, ok, limit):
    """One round's greedy independent set of ``cand`` (priority order): the rows taken, in that order.

    A candidate is taken unless a row taken before is in its list or has it
    in its own list; when ``ok`` (n,) bool is not empty, it must also have
    ok[row] (the coverage test, on the lists as they are at the start of the
    round, so filtering the candidates first gives the same set). Stops
    after ``limit`` rows (limit < 0: no limit): the first ``limit`` of the
    whole set, since the pass is sequential.
    """
    n = len(kk)
    K = nb.shape[1]
    test = len(ok) > 0
    state = np.zeros(n, dtype=np.uint8)  # 0 free, 1 taken, 2 in a taken row's list
    out = np.empty(len(cand), dtype=np.int64)
    t = 0
    for i in range(len(cand)):
        if t == limit:
            break
        y = cand[i]
        if state[y] != 0 or (test and not ok[y]):
            continue
        ky = min(kk[y], K)
        free = True
        for j in range(ky):
            x = nb[y, j]
            if 0 <= x < n and state[x] == 1:
                free = False
                break
        if not free:
            continue
        state[y] = 1
        out[t] = y
        t += 1
        for j in range(ky):
            x = nb[y, j]
            if 0 <= x < n and state[x] == 0:
                state[x] = 2
    return out[:t]


@njit(cache=True, nogil=True)
def _sort_key(v):
    """uint64 in the order of the float64 v (-0.0 as 0.0; no NaN)."""
    b = np.array([v + 0.0]).view(np.uint64)[0]
    if b >> np.uint64(63):
        return ~b
    return b | (np.uint64(1) << np.uint64(63))


@njit(cache=True, nogil=True)
def _radix_order(keys, m, kb, kb2, ib, ib2, count):
    """The stable order of keys[:m] (float64, no NaN): a byte-wise radix sort skipping the bytes
    all keys share (few in one cluster). ``kb``, ``kb2`` (uint64), ``ib``, ``ib2`` (int64) of
    length >= m and ``count`` (256,) int64 are scratch; returns a view of ``ib`` or ``ib2``."""
    same_or = np.uint64(0)
    same_and = ~np.uint64(0)
    for i in range(m):
        u = _sort_key(keys[i])
        kb[i] = u
        ib[i] = i
        same_or |= u
        same_and &= u
    varies = same_or ^ same_and
    a_k, a_i, b_k, b_i = kb, ib, kb2, ib2
    for p in range(8):
        sh = np.uint64(8 * p)
        if (varies >> sh) & np.uint64(255) == 0:
            continue
        count[:] = 0
        for i in range(m):
            count[(a_k[i] >> sh) & np.uint64(255)] += 1
        tot = 0
        for d in range(256):
            c = count[d]
            count[d] = tot
            tot += c
        for i in range(m):
            d = (a_k[i] >> sh) & np.uint64(255)
            o = count[d]
            count[d] = o + 1
            b_k[o] = a_k[i]
            b_i[o] = a_i[i]
        a_k, b_k = b_k, a_k
        a_i, b_i = b_i, a_i
    return a_i[:m]


@njit(cache=True, nogil=True)
def select_clusters(starts, alive, val, threshold, any_finite, tie, nb, kk, ok):
    """The greedy independent sets of one round when every list stays inside its cluster.

    Rows are grouped by cluster (cluster j: rows starts[j] to starts[j + 1]).
    The candidates (alive, val <= threshold, or finite val with
    ``any_finite``) are taken in the order (val, tie) as in
    :func:`select_round`; since no list leaves its cluster, a row's fate
    depends only on the candidates of its cluster before it, so each cluster
    is ordered and run on its own (small sorts, memory at hand). Returns the
    rows taken (int64, cluster by cluster): the whole set of
    :func:`select_round` without limit, in another order.
    """
    n = len(kk)
    K = nb.shape[1]
    test = len(ok) > 0
    M = 1
    for c in range(len(starts) - 1):
        M = max(M, starts[c + 1] - starts[c])
    cand = np.empty(M, dtype=np.int64)
    keys = np.empty(M)
    kb = np.empty(M, dtype=np.uint64)
    kb2 = np.empty(M, dtype=np.uint64)
    ib = np.empty(M, dtype=np.int64)
    ib2 = np.empty(M, dtype=np.int64)
    count = np.zeros(256, dtype=np.int64)
    srt = np.empty(M, dtype=np.int64)
    skeys = np.empty(M)
    state = np.zeros(n, dtype=np.uint8)  # 0 free, 1 taken, 2 in a taken row's list
    out = np.empty(n, dtype=np.int64)
    t = 0
    for c in range(len(starts) - 1):
        m = 0
        for i in range(starts[c], starts[c + 1]):
            if alive[i] and (np.isfinite(val[i]) if any_finite else val[i] <= threshold):
                cand[m] = i
                keys[m] = val[i]
                m += 1
        if m == 0:
            continue
        o = _radix_order(keys, m, kb, kb2, ib, ib2, count)
        for i in range(m):
            srt[i] = cand[o[i]]
            skeys[i] = keys[o[i]]
        break_ties(srt[:m], skeys[:m], tie)
        for i in range(m):
            y = srt[i]
            if state[y] != 0 or (test and not ok[y]):
                continue
            ky = min(kk[y], K)
            free = True
            for j in range(ky):
                x = nb[y, j]
                if 0 <= x < n and state[x] == 1:
                    free = False
                    break
            if not free:
                continue
            state[y] = 1
            out[t] = y
            t += 1
            for j in range(ky):
                x = nb[y, j]
                if 0 <= x < n and state[x] == 0:
                    state[x] = 2
    return out[:t].copy()


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
def refresh_lists(P, ginv, starts, alive, dup, q, kcl, extra, width):
    """New lists for the rows ``q`` (ascending) among the alive distinct rows of their cluster, by brute force.

    Row y of cluster j gets k = kcl[j] and its L = k + 1 + e nearest, e =
    min(extra, m - k - 2) (m: the cluster's alive distinct rows), nearest
    first, as the k-d tree query of :func:`cloudsieve.core.knn.knn_query`
    would return them: squared distances summed as the tree does, so the
    same values. The tree's list is the sorted one whenever the squared
    distances to the L + 1 nearest are all different (ties aside, no two
    exact k-NN lists differ); otherwise the row is flagged for the tree.

    Returns
    -------
    lists : ndarray of shape (len(q), width), int64
        The lists, padded with n.
    kq : ndarray of shape (len(q),), int64
    rk, rk1, r1 : ndarrays of shape (len(q),), float64
        r_k, r_(k+1) and r_1 of each row.
    status : ndarray of shape (len(q),), int8
        0 done, 1 a tie (ask the tree), 2 a zero distance to another row
        (the tree would flag the cluster as holding copies).
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
            # the L + 1 smallest (itself excluded): a threshold t with L + 1 to ~2 (L + 1) values
            # <= t (counted without branches, t from the previous row's), those values ranked
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
                lo = 0.0
                hi = np.inf
                for _ in range(200):
                    cnt = 0
                    for a in range(m):
                        cnt += (sq[a] <= t) & (a != sp)
                    if cnt < need:
                        lo = t
                        t = t * 2.0 if hi == np.inf else (t + hi) / 2
                    elif cnt > 2 * need + 4:
                        hi = t
                        t = (lo + t) / 2
                    else:
                        break
                if cnt < need:  # t did not settle (huge spread): take every value
                    t = np.inf
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
                t = bs[need - 1] * 1.25
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


@njit(cache=True, nogil=True)
def drop_rows(sel, alive, val, kk, r1, nb, ginv, touched):
    """Remove the rows ``sel``: dead, val and r1 +inf, no list; mark their clusters in ``touched``."""
    n = len(kk)
    for y in sel:
        alive[y] = False
        val[y] = np.inf
        r1[y] = np.inf
        kk[y] = 0
        nb[y, :] = n
        touched[ginv[y]] = True


@njit(cache=True, nogil=True)
def cluster_counts(ginv, alive, dup, c):
    """Per cluster: alive distinct rows (m) and alive copies; two (c,) int64 arrays."""
    m = np.zeros(c, dtype=np.int64)
    copies = np.zeros(c, dtype=np.int64)
    for i in range(len(ginv)):
        if alive[i]:
            if dup[i]:
                copies[ginv[i]] += 1
            else:
                m[ginv[i]] += 1
    return m, copies


@njit(cache=True, nogil=True)
def repack_lists(P, ginv, kk, rk, rk1, r1, nb, part, k_new, sel):
    """Drop the removed rows ``sel`` from the lists of the rows of the ``part`` clusters.

    A list (nearest first, padded with n) that lost an entry, or whose
    cluster's k changed to k' = ``k_new``, is packed; if it still holds
    k' + 1 rows, they are the k' + 1 nearest of the remaining ones (removing
    rows brings none closer), so kk = k', r_k and r_(k+1) are the distances
    to its k'-th and (k'+1)-th entries (and r1 to its first, when that
    changed). The other rows (their list is packed, kk unchanged) are
    returned, ascending: they need a new k-NN query.
    """
    n = len(kk)
    W = nb.shape[1]
    removed = np.zeros(n + 1, dtype=np.bool_)  # slot n: the padding
    for y in sel:
        removed[y] = True
    short = np.empty(n, dtype=np.int64)
    ns = 0
    for row in range(n):
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
def scored_rows(touched, ginv, kk):
    """The rows with a list (kk > 0) in the ``touched`` clusters, ascending (int64)."""
    n = len(kk)
    rows = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if kk[i] > 0 and touched[ginv[i]]:
            rows[m] = i
            m += 1
    return rows[:m].copy()


@njit(cache=True, nogil=True)
def log_weights(rows, ginv, c, lr, lr1, neg_dim):
    """log w and log w' (r_k replaced by r_(k+1)) of the rows, shifted per cluster so the largest w is 1.

    ``lr``, ``lr1`` (M,) are log r_k and log r_(k+1); ``neg_dim`` = -d.
    Returns lw, lw1 (M,) float64: -d (log r - min over the cluster of log r_k).
    """
    M = len(rows)
    shift = np.full(c, np.inf)
    for i in range(M):
        cl = ginv[rows[i]]
        if lr[i] < shift[cl]:
            shift[cl] = lr[i]
    lw = np.empty(M)
    lw1 = np.empty(M)
    for i in range(M):
        s = shift[ginv[rows[i]]]
        lw[i] = neg_dim * (lr[i] - s)
        lw1[i] = neg_dim * (lr1[i] - s)
    return lw, lw1


@njit(cache=True, nogil=True)
def entropy_deltas(rows, ginv, c, kk, nb, w, w1, lw, lw1, acc_w, acc_g):
    """The changes of W and G when each row leaves its cluster, and its cluster's W.

    With w = r_k^-d (``w``, ``lw`` = log w), w' the weight with r_(k+1)
    (``w1``, ``lw1``), W = sum w and A = sum w log w per cluster (ascending
    rows), g = w (log w - A/W): a row x's change (w' - w, g' - g) goes to the
    rows of its list's first kk[x] entries; the change of removing y is then
    (sum of what y received - w(y), the same for g). ``acc_w``/``acc_g`` (n,)
    are scratch (overwritten at ``rows``).

    Returns
    -------
    dW, dG, W : three ndarrays of shape (M,), float64
    """
    M = len(rows)
    Wc = np.zeros(c)
    Ac = np.zeros(c)
    for i in range(M):
        cl = ginv[rows[i]]
        Wc[cl] += w[i]
        Ac[cl] += w[i] * lw[i]
    gw = np.empty(M)
    dw = np.empty(M)
    dg = np.empty(M)
    for i in range(M):
        cl = ginv[rows[i]]
        L = Ac[cl] / Wc[cl]
        g = w[i] * (lw[i] - L)
        g1 = w1[i] * (lw1[i] - L)
        gw[i] = g
        dw[i] = w1[i] - w[i]  # exactly 0 when r_(k+1) = r_k (ties)
        dg[i] = g1 - g
        acc_w[rows[i]] = 0.0
        acc_g[rows[i]] = 0.0
    for i in range(M):
        r = rows[i]
        for j in range(kk[r]):
            t = nb[r, j]
            acc_w[t] += dw[i]
            acc_g[t] += dg[i]
    dW = np.empty(M)
    dG = np.empty(M)
    W = np.empty(M)
    for i in range(M):
        r = rows[i]
        dW[i] = acc_w[r] - w[i]
        dG[i] = acc_g[r] - gw[i]
        W[i] = Wc[ginv[r]]
    return dW, dG, W


@njit(cache=True, nogil=True)
def store_scores(rows, ginv, dh, m, use_unit, val):
    """val[rows] = dH, or m * dH (``m`` (c,) the clusters' distinct alive rows) with ``use_unit``."""
    for i in range(len(rows)):
        v = dh[i]
        if use_unit:
            v = v * m[ginv[rows[i]]]
        val[rows[i]] = v
