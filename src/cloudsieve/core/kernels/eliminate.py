"""Compiled kernels of weighted sample elimination (numba; private, inputs assumed valid).

The caller (:mod:`cloudsieve.core.eliminate`) puts the points in a canonical
internal order (by grid cell along a Z-order curve, then by coordinates) and
passes, in that order:

- ``P`` (n, 3) float64, ``cell`` (n,) int64 the cell of each point, ``cstart``
  (C + 1,) the first point of each cell, ``nstart``/``ncells`` the CSR list of
  the occupied cells among the 27 around each cell (cells are at least as
  wide as every search radius);
- ``state`` (n,) uint8: 0 absent (removed, or an exact copy), 1 alive and
  removable, 2 alive and fixed (weighs on the others, never removed);
- ``scale`` (n,) float64 > 0: the information multiplier of each weight;
- ``imp2`` (n,) float64 > 0: the squared importance m^2 of each point;
- ``tie`` (n,) int64 distinct ids: equal keys go lower id first.

Key of an alive point x (larger goes first)::

    key(x) = scale[x] * w(x) * f(x)
    w(x) = sum over alive y != x with d(x, y) < 2 r_max of (1 - d(x, y) / (2 r_max)) ** alpha
    f(x) = g(max(1, m) e(x)) / (1 + lam m^2 c(x) / r_max^2)     (1 without the coverage terms)

where x represents itself and every removed point whose nearest remaining
point it is, e(x) is the largest distance from one of them to its nearest
other remaining point, c(x) the sum of the squared distances they would gain
if x went, g(e) = 1 for e <= r_cov, else (r_cov / e) ** gamma.

Every factor only decreases as points go (fewer neighbours; represented sets
grow; nearest other points only get farther), so a stored key is an upper
bound of the current key and a lazy max-heap is exact: pop the top, recompute
its key (always from scratch and in the same summation order, never by
subtraction, so no rounding drift), equal to the stored key -> it is the
heaviest point, remove it; lower -> store the new key and sift it down. The
order is the one of an eager heap recomputing every key after each removal.
The heap is two-level (a heap per block of 1024 consecutive points, and a
heap of the blocks' tops) so that sifts stay in cache.

Grid arguments as in :mod:`.grid`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .neighbours import list_nearest, list_weight

BLOCK = 1024


@njit(cache=True)
def _coverage(x, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, head, nxt, alt, altd2, rc2, gamma,
              lam, inv_r2, imp2, stats):
    """f(x) of the module docstring; refreshes the cached nearest other point of the points x represents."""
    e2 = 0.0
    c2 = 0.0
    p = head[x]
    while p >= 0:
        a = alt[p]
        if a < 0 or state[a] == 0:
            stats[3] += 1
            a, d2 = list_nearest(p, x, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr)
            alt[p] = a
            altd2[p] = d2
        if a < 0:
            return 0.0
        d2 = altd2[p]
        e2 = max(e2, d2)
        dx = P[p, 0] - P[x, 0]
        dy = P[p, 1] - P[x, 1]
        dz = P[p, 2] - P[x, 2]
        c2 += d2 - (dx * dx + dy * dy + dz * dz)
        p = nxt[p]
    e2 *= max(imp2[x], 1.0)
    c2 *= imp2[x]
    f = 1.0
    if rc2 > 0 and e2 > rc2:
        f = (rc2 / e2) ** (0.5 * gamma)
    return f / (1.0 + lam * c2 * inv_r2)


@njit(cache=True)
def _sift(hk, hi, tie, base, size, pos):
    """Sift entry ``pos`` of the heap hk/hi[base:base + size] down (larger key first, then lower tie)."""
    k = hk[base + pos]
    i = hi[base + pos]
    while True:
        c = 2 * pos + 1
        if c >= size:
            break
        a = base + c
        if c + 1 < size and (hk[a + 1] > hk[a] or (hk[a + 1] == hk[a] and tie[hi[a + 1]] < tie[hi[a]])):
            c += 1
            a += 1
        if not (hk[a] > k or (hk[a] == k and tie[hi[a]] < tie[i])):
            break
        hk[base + pos] = hk[a]
        hi[base + pos] = hi[a]
        pos = c
    hk[base + pos] = k
    hi[base + pos] = i


@njit(cache=True)
def eliminate(P, cell, cstart, nstart, ncells, nptr, nbr, term, state, scale, imp2, w, tie, two_r, r_cov, gamma,
              lam, floor):
    """Remove removable points, largest key first, until ``floor`` of them remain.

    ``nptr``/``nbr``/``term`` the neighbour lists and ``w`` the weights of
    :mod:`.neighbours`; ``imp2`` (n,) the squared importance
    of each point: its coverage and squared-error terms are measured in
    distances times its importance. Returns priority (n,): the key of each
    point when it was removed (non-increasing along the removals); the points
    left get their stored keys (upper bounds, still <= every removed key);
    NaN for points that were not removable. ``state`` is consumed. Also
    returns counts (4,): pops, stale pops, coverage evaluations, nearest searches.
    """
    n = len(P)
    inv2r = 1.0 / two_r
    inv_r2 = 4.0 * inv2r * inv2r
    cover = r_cov > 0 or lam > 0
    head = np.full(n, -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    alt = np.full(n, -1, dtype=np.int64)
    altd2 = np.full(n, np.inf)
    fac = np.ones(n)
    for i in range(n):
        if state[i] != 0:
            head[i] = i
    nb = (n + BLOCK - 1) // BLOCK
    hk = np.empty(n)
    hi = np.empty(n, dtype=np.int64)
    bsize = np.zeros(nb, dtype=np.int64)
    for i in range(n):
        if state[i] == 1:
            b = i // BLOCK
            hk[b * BLOCK + bsize[b]] = w[i]
            hi[b * BLOCK + bsize[b]] = i
            bsize[b] += 1
    tk = np.empty(nb)  # heap of the blocks' tops: key, then the block (tie through its top point)
    tb = np.empty(nb, dtype=np.int64)
    btie = np.empty(nb, dtype=np.int64)
    ts = 0
    for b in range(nb):
        for pos in range(bsize[b] // 2 - 1, -1, -1):
            _sift(hk, hi, tie, b * BLOCK, bsize[b], pos)
        if bsize[b] > 0:
            tk[ts] = hk[b * BLOCK]
            tb[ts] = b
            btie[b] = tie[hi[b * BLOCK]]
            ts += 1
    for pos in range(ts // 2 - 1, -1, -1):
        _sift(tk, tb, btie, 0, ts, pos)
    prio = np.full(n, np.nan)
    stats = np.zeros(4, dtype=np.int64)  # pops, stale pops, coverage evaluations, nearest searches
    left = 0
    for b in range(nb):
        left += bsize[b]
    while left > floor:
        b = tb[0]
        base = b * BLOCK
        i = hi[base]
        key = hk[base]
        stats[0] += 1
        cur = scale[i] * list_weight(i, nptr, nbr, term, state)
        if cover:
            if cur * fac[i] >= key:
                stats[2] += 1
                f = _coverage(i, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, head, nxt, alt, altd2,
                              r_cov * r_cov, gamma, lam, inv_r2, imp2, stats)
                fac[i] = min(fac[i], f)
            cur = cur * fac[i]
        if cur < key:  # stale: store the current key
            stats[1] += 1
            hk[base] = cur
        else:
            prio[i] = key
            state[i] = 0
            left -= 1
            if cover:  # the points i represented move to their nearest other point
                p = head[i]
                while p >= 0:
                    q = nxt[p]
                    a = alt[p]
                    if a >= 0:
                        nxt[p] = head[a]
                        head[a] = p
                    alt[p] = -1
                    p = q
                head[i] = -1
            bsize[b] -= 1
            if bsize[b] > 0:
                hk[base] = hk[base + bsize[b]]
                hi[base] = hi[base + bsize[b]]
        if bsize[b] > 0:
            _sift(hk, hi, tie, base, bsize[b], 0)
            tk[0] = hk[base]
            btie[b] = tie[hi[base]]
        else:
            ts -= 1
            tk[0] = tk[ts]
            tb[0] = tb[ts]
        _sift(tk, tb, btie, 0, ts, 0)
    for b in range(nb):
        for pos in range(bsize[b]):
            prio[hi[b * BLOCK + pos]] = hk[b * BLOCK + pos]
    return prio, stats


@njit(cache=True)
def relocate(P, near, kept, movable, tie, rcon2):
    """One restricted Lloyd step: each movable kept point k moves to the movable point of its Voronoi
    region (the points whose ``near`` is k) nearest the region's centroid, unless that would take some
    point of the region farther than max(the region's current farthest, sqrt(rcon2)). Near-ties
    (relative 1e-9) keep k, then the lower ``tie``, so rounding never decides. Returns the new flags."""
    n = len(P)
    cnt = np.zeros(n)
    cen = np.zeros((n, 3))
    far = np.zeros(n)
    for p in range(n):
        k = near[p]
        if k < 0:
            continue
        cnt[k] += 1.0
        for j in range(3):
            cen[k, j] += P[p, j]
        far[k] = max(far[k], (P[p, 0] - P[k, 0]) ** 2 + (P[p, 1] - P[k, 1]) ** 2 + (P[p, 2] - P[k, 2]) ** 2)
    for k in range(n):
        if cnt[k] > 0:
            for j in range(3):
                cen[k, j] /= cnt[k]
    best = np.full(n, -1, dtype=np.int64)
    bd = np.full(n, np.inf)
    for k in range(n):
        if cnt[k] > 0 and movable[k] != 0:
            best[k] = k
            bd[k] = (P[k, 0] - cen[k, 0]) ** 2 + (P[k, 1] - cen[k, 1]) ** 2 + (P[k, 2] - cen[k, 2]) ** 2
    slack = 1.0 - 1e-9
    for p in range(n):
        k = near[p]
        if k < 0 or p == k or movable[p] == 0 or best[k] < 0:
            continue
        d2 = (P[p, 0] - cen[k, 0]) ** 2 + (P[p, 1] - cen[k, 1]) ** 2 + (P[p, 2] - cen[k, 2]) ** 2
        b = best[k]
        if b == k:
            if d2 < bd[k] * slack:
                best[k] = p
                bd[k] = d2
        elif d2 < bd[k] * slack or (d2 <= bd[k] / slack and tie[p] < tie[b]):
            best[k] = p
            bd[k] = min(d2, bd[k])
    worst = np.zeros(n)
    for p in range(n):
        k = near[p]
        if k >= 0 and best[k] >= 0 and best[k] != k:
            b = best[k]
            worst[k] = max(worst[k], (P[p, 0] - P[b, 0]) ** 2 + (P[p, 1] - P[b, 1]) ** 2 + (P[p, 2] - P[b, 2]) ** 2)
    out = kept.copy()
    for k in range(n):
        b = best[k]
        if b >= 0 and b != k and worst[k] <= max(far[k], rcon2) * (1.0 + 1e-9):
            out[k] = 0
            out[b] = 1
    return out
