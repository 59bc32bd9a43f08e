"""The grouped order of the points, compiled with numba (see :func:`cloudsieve.core.knn.group`).

Clusters in id order, each in Z-order of its first three coordinates, ties in
input order: ``np.argsort(code | id << 3 bits, kind="stable")`` computed as a
counting sort by cluster and a stable sort per cluster. Codes are
``uint64((x - lo) * scale)`` per coordinate, bits spread three apart.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["grouped_order", "radix_passes", "stable_argsort"]


@njit(cache=True, nogil=True, inline="always")
def _spread(x):
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@njit(cache=True, nogil=True, _nrt=False)
def stable_sort(key, idx, m, k2, i2):
    """Stable sort of idx[:m] by key[:m] (keys moved along): runs of 16 by insertion, then merges (k2, i2 scratch)."""
    for a in range(0, m, 16):
        b = min(a + 16, m)
        for u in range(a + 1, b):
            x = key[u]
            y = idx[u]
            p = u
            while p > a and key[p - 1] > x:
                key[p] = key[p - 1]
                idx[p] = idx[p - 1]
                p -= 1
            key[p] = x
            idx[p] = y
    w = 16
    src_k, src_i, dst_k, dst_i = key, idx, k2, i2
    while w < m:
        for a in range(0, m, 2 * w):
            mid = min(a + w, m)
            b = min(a + 2 * w, m)
            i = a
            j = mid
            for t in range(a, b):
                if j >= b or (i < mid and src_k[i] <= src_k[j]):
                    dst_k[t] = src_k[i]
                    dst_i[t] = src_i[i]
                    i += 1
                else:
                    dst_k[t] = src_k[j]
                    dst_i[t] = src_i[j]
                    j += 1
        src_k, src_i, dst_k, dst_i = dst_k, dst_i, src_k, src_i
        w *= 2
    if src_i is not idx:
        for t in range(m):
            idx[t] = src_i[t]


@njit(cache=True, nogil=True)
def _grouped_order(pts, inv, c, bits, q):
    n = len(pts)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(n):  # the bounding box (min and max are exact: numpy's values)
        for d in range(q):
            lo[d] = min(lo[d], pts[i, d])
            hi[d] = max(hi[d], pts[i, d])
    span = -np.inf
    for d in range(q):
        span = max(span, hi[d] - lo[d])
    scale = 0.0
    if np.isfinite(span) and span > 0:
        scale = ((1 << bits) - 1) / span
    else:
        q = 0  # every code 0: input order
    start = np.zeros(c + 1, np.int64)
    for i in range(n):
        start[inv[i] + 1] += 1
    for j in range(c):
        start[j + 1] += start[j]
    order = np.empty(n, np.int64)
    fill = start[:-1].copy()
    for i in range(n):  # counting sort: input order inside each cluster
        j = inv[i]
        order[fill[j]] = i
        fill[j] += 1
    if q == 0:
        return order, start
    allc = np.empty(n, np.uint64)
    for i in range(n):  # the codes in input order (sequential reads)
        x = np.uint64(0)
        for d in range(q):
            x |= _spread(np.uint64((pts[i, d] - lo[d]) * scale)) << np.uint64(d)
        allc[i] = x
    mmax = 0
    for j in range(c):
        mmax = max(mmax, start[j + 1] - start[j])
    code = np.empty(mmax, np.uint64)
    idx = np.empty(mmax, np.int64)
    k2 = np.empty(mmax, np.uint64)
    i2 = np.empty(mmax, np.int64)
    for j in range(c):
        a = start[j]
        m = start[j + 1] - a
        if m < 2:
            continue
        for t in range(m):
            idx[t] = order[a + t]
            code[t] = allc[idx[t]]
        stable_sort(code, idx, m, k2, i2)  # equal codes keep input order
        for t in range(m):
            order[a + t] = idx[t]
    return order, start


def grouped_order(pts, inv, c, bits):
    """Input indices in grouped order (n,) and cluster starts ``indptr`` (c + 1,), both int64.

    ``inv`` (n,): cluster ids in 0..c-1; ``bits`` per coordinate of the codes, with
    3 * bits + bits of c - 1 <= 63.
    """
    q = min(pts.shape[1], 3) if len(pts) else 0
    return _grouped_order(pts, np.ascontiguousarray(inv, dtype=np.int64), int(c), int(bits), q)


@njit(cache=True, nogil=True)
def _radix_argsort(x):
    n = len(x)
    y = np.empty(n)
    for i in range(n):
        y[i] = x[i] + 0.0  # -0.0 becomes 0.0: equal keys, as the comparisons of a sort see them
    key = y.view(np.uint64)
    top = np.uint64(1) << np.uint64(63)
    hist = np.zeros((8, 256), np.int64)  # bytes: twice as fast as 11- or 16-bit digits
    for i in range(n):  # the order of the floats as unsigned integers
        u = key[i]
        u = ~u if u & top else u | top
        key[i] = u
        for p in range(8):
            hist[p, (u >> np.uint64(8 * p)) & np.uint64(255)] += 1
    return radix_passes(key, hist, 8)


@njit(cache=True, nogil=True)
def radix_passes(key, hist, passes):
    """Stable order (n,) int64 of uint64 ``key`` by its ``passes`` lowest bytes (LSD, shared bytes skipped); ``key`` is consumed."""
    n = len(key)
    idx = np.arange(n)
    k2 = np.empty(n, np.uint64)
    i2 = np.empty(n, np.int64)
    pos = np.empty(256, np.int64)
    for p in range(passes):  # each pass stable
        h = hist[p]
        if h.max() == n:
            continue
        acc = 0
        for b in range(256):
            pos[b] = acc
            acc += h[b]
        sh = np.uint64(8 * p)
        for i in range(n):
            u = key[i]
            b = (u >> sh) & np.uint64(255)
            j = pos[b]
            k2[j] = u
            i2[j] = idx[i]
            pos[b] = j + 1
        key, k2 = k2, key
        idx, i2 = i2, idx
    return idx


def stable_argsort(x):
    """``np.argsort(x, kind="stable")`` of float64 x (n,) without NaN, by an LSD radix sort (-0.0 equals 0.0); int64 (n,)."""
    return _radix_argsort(np.ascontiguousarray(x, dtype=np.float64))
