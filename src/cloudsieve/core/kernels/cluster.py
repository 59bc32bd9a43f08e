"""Compiled kernels of :mod:`cloudsieve.core.cluster` (numba; private: inputs are assumed valid).

:func:`kmeanspp_steps` (k-means++ draws and updates), :func:`take_rows` and
:func:`put_rows`. Floating point as in :mod:`.kmeans`, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kmeans import pairwise_sum

__all__ = ["kmeanspp_steps", "take_rows", "put_rows"]


@njit(cache=True, nogil=True, inline="always")
def _search_right(a, lo, n, v):
    """np.searchsorted(a[lo:lo + n], v, side="right") for ascending a."""
    b, e = 0, n
    while b < e:
        m = (b + e) // 2
        if a[lo + m] <= v:
            b = m + 1
        else:
            e = m
    return b


@njit(cache=True, nogil=True, inline="always")
def _search_left(a, n, v):
    """np.searchsorted(a[:n], v, side="left") for ascending a."""
    b, e = 0, n
    while b < e:
        m = (b + e) // 2
        if a[m] < v:
            b = m + 1
        else:
            e = m
    return b


@njit(cache=True, nogil=True)
def kmeanspp_steps(S, d2, bsum, bmax, chosen, k, u, forced, B):
    """Steps k, k+1, ... of the k-means++ seeding of ``cluster._kmeanspp``.

    S (s, p): the sample sorted on its first coordinate; d2 (nb * B,): squared
    distance to the nearest chosen centre (zero padded); bsum / bmax (nb,): its
    per-block sums and maxima; chosen (c,): the picks. A step draws with probability
    d2 / sum(d2) from u (or takes ``forced`` >= 0 at step k), then lowers d2 in the
    window found by binary search on the first coordinate. Returns (step reached,
    uniforms used); a step short of len(chosen) has d2 all zero (the caller draws with ``rng.integers``).
    """
    s, p = S.shape
    nb = len(bsum)
    c = len(chosen)
    cum = np.empty(nb)
    used = 0
    for t in range(k, c):
        if t == k and forced >= 0:
            nxt = forced
        else:
            anypos = False
            for b in range(nb):
                if bsum[b] > 0:
                    anypos = True
                    break
            if not anypos:
                return t, used
            acc = bsum[0]
            cum[0] = acc
            for b in range(1, nb):
                acc += bsum[b]
                cum[b] = acc
            r = u[used] * cum[nb - 1]
            used += 1
            b = min(_search_right(cum, 0, nb, r), nb - 1)
            if b:
                r -= cum[b - 1]
            else:
                r -= 0.0
            # the cumulative sum within block b, searched from its start
            acc = 0.0
            w = B - 1
            for q in range(B):
                acc = d2[b * B] if q == 0 else acc + d2[b * B + q]
                if acc > r:
                    w = q
                    break
            nxt = b * B + w
            while nxt >= s or d2[nxt] == 0:
                nxt -= 1
        chosen[t] = nxt
        big = bmax[0]
        for b in range(1, nb):
            if bmax[b] > big:
                big = bmax[b]
        reach = math.sqrt(big)
        lo = _search_left(S[:, 0], s, S[nxt, 0] - reach)
        hi = _search_right(S[:, 0], 0, s, S[nxt, 0] + reach)
        lo = (lo // B) * B
        hi = min(-(-hi // B) * B, s)
        for i in range(lo, hi):
            dn = 0.0
            for j in range(p):
                diff = S[i, j] - S[nxt, j]
                dn += diff * diff
            if dn < d2[i]:
                d2[i] = dn
        for b in range(lo // B, -(-hi // B)):
            bsum[b] = 0.0 + pairwise_sum(d2, b * B, B)
            m = d2[b * B]
            for q in range(1, B):
                if d2[b * B + q] > m:
                    m = d2[b * B + q]
            bmax[b] = m
    return c, used


@njit(cache=True, nogil=True)
def take_rows(src, order, dst, s, e):
    """dst[i] = src[order[i]] for i in s..e-1 (2-D arrays, rows)."""
    for i in range(s, e):
        o = order[i]
        for j in range(src.shape[1]):
            dst[i, j] = src[o, j]


@njit(cache=True, nogil=True)
def put_rows(src, order, dst, s, e):
    """dst[order[i]] = src[i] for i in s..e-1 (2-D arrays, rows)."""
    for i in range(s, e):
        o = order[i]
        for j in range(src.shape[1]):
            dst[o, j] = src[i, j]
