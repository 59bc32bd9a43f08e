"""Compiled kernels of one round of the ``iterative`` and ``coverage`` rules (numba; private, inputs assumed valid).

State of the rounds (:mod:`cloudsieve.core.rounds`), flat over n rows:

- ``nb`` (n, W) int32 or int64: neighbour lists, nearest first; entries outside
  [0, n) are none; only the first ``kk[row]`` columns count (0: no list);
- ``val`` (n,) float64 scores, ``alive`` (n,) bool, ``ginv`` (n,) int64 cluster,
  ``dup`` (n,) bool exact copies;
- without context, rows grouped by cluster and lists inside their cluster, so
  kernels over a cluster range (c0, c1) run on threads.

Lists between rounds: :mod:`.lists`; rescoring: :mod:`.rescore`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def candidates(alive, val, threshold, any_finite):
    """The alive rows with val <= threshold (``any_finite``: with a finite val), ascending: pool (m,) int64, keys (m,) float64."""
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
    """Sort each run of equal ``keys`` of ``cand`` by ``tie``, in place: the order (val, tie)."""
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


@njit(cache=True, nogil=True, _nrt=False)
def _sort_key(b):
    """uint64 in the order of the float64 whose bits are b (-0.0 as 0.0; no NaN)."""
    if b == np.uint64(1) << np.uint64(63):  # -0.0
        b = np.uint64(0)
    if b >> np.uint64(63):
        return ~b
    return b | (np.uint64(1) << np.uint64(63))


@njit(cache=True, nogil=True)
def _radix_order(keys, m, kb, kb2, ib, ib2, count):
    """Stable order of keys[:m] (float64, no NaN): a byte-wise radix sort skipping the bytes all keys share.

    ``kb``, ``kb2``, ``ib``, ``ib2`` (length >= m) and ``count`` (256,) are scratch; returns a view of ``ib`` or ``ib2``.
    """
    same_or = np.uint64(0)
    same_and = ~np.uint64(0)
    bits = keys.view(np.uint64)  # the keys' bits, without an array per key
    for i in range(m):
        u = _sort_key(bits[i])
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
def select_round(cand, nb, kk, ok, limit):
    """One round's greedy independent set of ``cand`` (priority order): the rows taken, in that order.

    A candidate is taken unless a taken row is in its list or lists it; with ``ok``
    (n,) not empty, it must also have ok[row] (the coverage test at round start).
    Stops after ``limit`` rows (< 0: no limit).
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


_HALF_MAX = np.finfo(np.float64).max / 2


@njit(cache=True, nogil=True, _nrt=False)
def _is_covered(nb, kk, r1, y, coverage, vals):
    """r_1(y) <= coverage * (median of r_1 over y's listed neighbours); False without neighbours.

    ``r1`` (n,) as :func:`.lists.spacings` gives it (+inf without a list); an even
    count's median is the mean of the middle two (``np.nanmedian``). Counting decides
    for 0 < coverage < inf except near the median or on overflow, where the values are
    sorted. ``vals``: scratch of length >= K.
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
def covered_rows(nb, kk, r1, coverage, a, b, ok):
    """ok[y] = the coverage test of rows a to b - 1; ``r1`` (n,) as :func:`.lists.spacings`."""
    vals = np.empty(max(nb.shape[1], 1))
    for y in range(a, b):
        ok[y] = kk[y] > 0 and _is_covered(nb, kk, r1, y, coverage, vals)


@njit(cache=True, nogil=True)
def covered_mask(nb, kk, r1, cand, coverage):
    """The coverage test of each candidate (bool (len(cand),)); see :func:`_is_covered`."""
    vals = np.empty(max(nb.shape[1], 1))
    ok = np.zeros(len(cand), dtype=np.bool_)
    for i in range(len(cand)):
        ok[i] = _is_covered(nb, kk, r1, cand[i], coverage, vals)
    return ok


@njit(cache=True, nogil=True)
def select_clusters(starts, c0, c1, alive, val, threshold, any_finite, tie, nb, kk, r1, coverage):
    """The greedy independent sets of one round for clusters c0 to c1 - 1, lists inside their cluster.

    Candidates (alive, val <= threshold, or finite val with ``any_finite``) in order
    (val, tie) as :func:`select_round`, each cluster on its own; with ``r1`` not empty
    also the coverage test (:func:`_is_covered`) where a candidate could be taken.
    Returns the rows taken, cluster by cluster: :func:`select_round`'s set without limit.
    """
    n = len(kk)
    K = nb.shape[1]
    test = len(r1) > 0
    vals = np.empty(max(K, 1))
    base = starts[c0]
    M = 1
    for c in range(c0, c1):
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
    state = np.zeros(starts[c1] - base, dtype=np.uint8)  # 0 free, 1 taken, 2 in a taken row's list
    out = np.empty(starts[c1] - base, dtype=np.int64)
    t = 0
    for c in range(c0, c1):
        m = np.int64(0)  # not the literal 0: one signature of _radix_order
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
            if state[y - base] != 0:
                continue
            ky = min(kk[y], K)
            free = True
            for j in range(ky):
                x = nb[y, j]
                if 0 <= x < n and state[x - base] == 1:
                    free = False
                    break
            if not free or (test and not _is_covered(nb, kk, r1, y, coverage, vals)):
                continue
            state[y - base] = 1
            out[t] = y
            t += 1
            for j in range(ky):
                x = nb[y, j]
                if 0 <= x < n and state[x - base] == 0:
                    state[x - base] = 2
    return out[:t].copy()


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
