"""Compiled kernels of weighted sample elimination (numba; private, inputs assumed valid).

In the canonical internal order of :class:`cloudsieve.core.cellgrid.CellGrid`, the caller passes
grid arguments as in :mod:`.grid` and:

- ``state`` (n,) uint8: 0 absent (removed or a copy), 1 removable, 2 fixed (weighs, never removed);
- ``scale`` (n,) float64 > 0: information multiplier of each weight;
- ``imp2`` (n,) float64 > 0: squared importance m^2;
- ``tie`` (n,) int64 distinct ids: equal keys go lower id first.

Key of an alive point x (larger goes first)::

    key(x) = scale[x] * w(x) * f(x)
    w(x) = sum over alive y != x with d(x, y) < 2 r_max of (1 - d(x, y) / (2 r_max)) ** alpha
    f(x) = g(max(1, m) e(x)) / (1 + lam m^2 c(x) / r_max^2)     (1 without the coverage terms)

with e, c as in :mod:`cloudsieve.core.eliminate`, g(e) = 1 for e <= r_cov, else (r_cov / e) ** gamma.

Every factor only decreases as points go (also in floating point: each is
computed from scratch in fixed order), so a winner tree over upper bounds of
the keys finds the order: the top's exact key is recomputed; if it still beats
the next bound it goes, else it is stored and the tree replayed (a stale pop).
The priorities equal an eager heap's. Neighbour lists (:mod:`.neighbours`)
replace grid walks except for a nearest point beyond 2 r_max.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .cover import add_gain, falloff, fbound, gain, resume_at, take_alt, unlink
from .neighbours import list_nearest, term_weight

# Helpers here, in .cover, .neighbours and .grid.nearest are plain calls, not inline="always": inlined,
# the kernels compile up to twice as long for the same run time


@njit(cache=True)
def _coverage(x, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, head, nxt, alt, altd2, rc2, gamma,
              lam, inv_r2, imp2, stats):
    """f(x) from scratch, in the order of x's list of represented points."""
    e2 = 0.0
    c2 = 0.0
    p = np.int64(head[x])
    while p >= 0:
        a = np.int64(alt[p])
        if a >= 0 and state[a] != 0:
            d2 = altd2[p]
        else:
            stats[3] += 1
            a, d2 = list_nearest(p, x, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr)
        if a < 0:
            return 0.0
        e2 = max(e2, d2)
        dx = P[p, 0] - P[x, 0]
        dy = P[p, 1] - P[x, 1]
        dz = P[p, 2] - P[x, 2]
        c2 += d2 - (dx * dx + dy * dy + dz * dz)
        p = np.int64(nxt[p])
    e2 *= max(imp2[x], 1.0)
    c2 *= imp2[x]
    f = 1.0
    if rc2 > 0 and e2 > rc2:
        f = falloff(rc2 / e2, gamma)
    return f / (1.0 + lam * c2 * inv_r2)


@njit(cache=True)
def _better(a, b, rec, tie):
    """Which of points a and b goes first (n: none): larger stored key rec[., 3], then lower tie; branch-free."""
    ka = rec[a, 3]
    kb = rec[b, 3]
    return a if (ka > kb) | ((ka == kb) & (tie[a] < tie[b])) else b


@njit(cache=True)
def _replay(win, v, i, rec, tie):
    """After the key of point i fell (or i left), replay the matches above node v that i had won."""
    while v >= 1 and win[v] == i:
        win[v] = _better(np.int64(win[2 * v]), np.int64(win[2 * v + 1]), rec, tie)
        v >>= 1


@njit(cache=True)
def _fall(y, rec, win, m, tie):
    """Store the bound scale * (running sum + margin) * factor of point y if lower, and replay the tree."""
    bd = rec[y, 1] * rec[y, 0] * rec[y, 2]
    if bd < rec[y, 3]:
        rec[y, 3] = bd
        _replay(win, (m + y) >> 1, y, rec, tie)


# A plain function: its allocations in numpy (compiled, they would lengthen the first start), the work in the kernel
def eliminate(P, cell, cstart, nstart, ncells, nptr, nbr, low, term, soff, state, scale, imp2, w, tie, two_r, alpha,
              ialpha, r_cov, gamma, lam, floor, nown, ci, gone_rep, keys_left=True):
    """Remove removable points, largest key first, until ``floor`` of the own ones (``tie`` < ``nown``) remain.

    ``nptr``/``nbr``/``low``/``soff`` and ``w`` (n,): neighbour lists and crowding sums of
    :mod:`.neighbours`; ``imp2`` (n,): squared importance. ``gone_rep`` (n,): the alive point
    representing each point gone from the start (-1: none). ``state`` and ``ci`` (n, 8)
    (all -1; int32 when the lists hold fewer than 2^31 entries) are consumed.

    Returns priority (n,): each point's key at removal (non-increasing), for own points
    left their keys at the stop (-1.0 without ``keys_left``), NaN for points not
    removable; and counts (4,): pops, stale pops, coverage evaluations, nearest searches.
    """
    n = len(P)
    cf = np.zeros((n, 8))
    rec = np.empty((n + 1, 4))  # row n: the tree's "none", key -inf
    rec[n, 3] = -np.inf
    tk = np.empty(n + 1, dtype=np.int64)  # the ties, "none" last
    tk[:n] = tie
    tk[n] = np.iinfo(np.int64).max
    stats = np.zeros(4, dtype=np.int64)  # pops, stale pops, coverage evaluations, nearest searches
    m = 1 << (max(n, 1) - 1).bit_length()  # the least power of 2 >= n
    win = np.full(2 * m, n, dtype=ci.dtype)  # the winner tree over the stored keys (leaves m .. m + n)
    prio = np.full(n, np.nan)
    _eliminate(P, cell, cstart, nstart, ncells, nptr, nbr, low, term, soff, state, scale, imp2, w, tie, two_r, alpha,
               ialpha, r_cov, gamma, lam, floor, nown, ci, gone_rep, cf, rec, stats, win, m, prio, tk, keys_left)
    return prio, stats


# No runtime reference counts: they cost atomic operations on each removal
@njit(cache=True, nogil=True, _nrt=False)
def _eliminate(P, cell, cstart, nstart, ncells, nptr, nbr, low, term, soff, state, scale, imp2, w, tie, two_r, alpha,
               ialpha, r_cov, gamma, lam, floor, nown, ci, gone_rep, cf, rec, stats, win, m, prio, tk, keys_left):
    n = len(P)
    inv2r = 1.0 / two_r
    inv_r2 = 4.0 * inv2r * inv2r
    rc2 = r_cov * r_cov
    cover = r_cov > 0 or lam > 0
    # the coverage data of each point in two rows (one cache line each): links, and distances and counts
    head, nxt, rep, alt, sp, ahead, anext, aprev = ci[:, 0], ci[:, 1], ci[:, 2], ci[:, 3], ci[:, 4], ci[:, 5], \
        ci[:, 6], ci[:, 7]
    altd2, e2b, c2b, cerr, nmem, nmiss = cf[:, 0], cf[:, 1], cf[:, 2], cf[:, 3], cf[:, 4], cf[:, 5]
    altd2[:] = np.inf
    # per point, in one row: running crowding sum (by subtraction) plus a margin above the rounding of it
    # and of the exact sum, scale, coverage factor bound, stored key bound (the winner tree's key)
    for i in range(n):
        rec[i, 0] = w[i] + (nptr[i + 1] - nptr[i] + 2) * 2.0**-50 * w[i]
        rec[i, 1] = scale[i]
        rec[i, 2] = 1.0
        rec[i, 3] = -1.0
        if state[i] != 0 and cover:
            head[i] = i
            rep[i] = i
            nmem[i] = 1.0
            take_alt(i, i, nptr[i], P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, soff, alt, altd2, sp,
                     ahead, anext, aprev, e2b, c2b, cerr, nmiss)
    for p in range(n):  # points already gone (a neighbouring cell's): represented by their nearest alive point
        a = gone_rep[p]
        if a >= 0 and cover:
            nxt[p] = head[a]
            head[a] = p
            rep[p] = a
            nmem[a] += 1.0
            take_alt(p, a, nptr[p], P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, soff, alt, altd2, sp,
                     ahead, anext, aprev, e2b, c2b, cerr, nmiss)
    left = 0
    for i in range(n):
        if state[i] == 1:
            if cover:
                rec[i, 2] = fbound(i, e2b, c2b, cerr, nmem, nmiss, imp2, rc2, gamma, lam, inv_r2)
            rec[i, 3] = rec[i, 1] * rec[i, 0] * rec[i, 2]
            win[m + i] = i
            if tie[i] < nown:
                left += 1
    for v in range(m - 1, 0, -1):
        win[v] = _better(np.int64(win[2 * v]), np.int64(win[2 * v + 1]), rec, tk)
    while left > floor:
        i = np.int64(win[1])
        ti = tie[i]
        stats[0] += 1
        r = np.int64(n)  # the next largest bound: the best of the matches i won
        v = m + i
        while v > 1:
            r = _better(r, np.int64(win[v ^ 1]), rec, tk)
            v >>= 1
        k2 = rec[r, 3] if r < n else -1.0
        t2 = tie[r] if r < n else 0
        wi = term_weight(i, nptr, nbr, state, term)
        rec[i, 0] = wi + (nptr[i + 1] - nptr[i] + 2) * 2.0**-50 * w[i]
        cur = scale[i] * wi
        if cover:
            if cur * rec[i, 2] > k2 or (cur * rec[i, 2] == k2 and ti < t2):
                stats[2] += 1
                f = _coverage(i, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, head, nxt, alt, altd2,
                              rc2, gamma, lam, inv_r2, imp2, stats)
                rec[i, 2] = min(rec[i, 2], f)
            cur = cur * rec[i, 2]
        if not (cur > k2 or (cur == k2 and ti < t2)):  # stale: store the exact key
            stats[1] += 1
            rec[i, 3] = cur
            _replay(win, (m + i) >> 1, i, rec, tk)
            continue
        prio[i] = cur
        state[i] = 0
        if ti < nown:
            left -= 1
        win[m + i] = n
        _replay(win, (m + i) >> 1, i, rec, tk)
        if cover:
            p = np.int64(head[i])  # the points i represented move to their alt
            while p >= 0:
                q = np.int64(nxt[p])
                a = np.int64(alt[p])
                if a < 0:
                    rep[p] = -1
                else:
                    unlink(p, a, ahead, anext, aprev)
                    nxt[p] = head[a]
                    head[a] = p
                    rep[p] = a
                    nmem[a] += 1.0
                    stats[3] += 1
                    take_alt(p, a, resume_at(p, sp, nptr), P, cell, cstart, nstart, ncells, state, tie, nptr, nbr,
                             soff, alt, altd2, sp, ahead, anext, aprev, e2b, c2b, cerr, nmiss)
                    if state[a] == 1:
                        rec[a, 2] = min(rec[a, 2], fbound(a, e2b, c2b, cerr, nmem, nmiss, imp2, rc2, gamma, lam,
                                                           inv_r2))
                        _fall(a, rec, win, m, tk)
                p = q
            head[i] = -1
            p = np.int64(ahead[i])  # the points whose alt was i get the next one
            while p >= 0:
                q = np.int64(anext[p])
                x = np.int64(rep[p])
                stats[3] += 1
                add_gain(x, -gain(p, x, altd2[p], P), c2b, cerr)  # its gain to the old alt goes
                take_alt(p, x, resume_at(p, sp, nptr), P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, soff,
                         alt, altd2, sp, ahead, anext, aprev, e2b, c2b, cerr, nmiss)
                if state[x] == 1:
                    rec[x, 2] = min(rec[x, 2], fbound(x, e2b, c2b, cerr, nmem, nmiss, imp2, rc2, gamma, lam,
                                                       inv_r2))
                    _fall(x, rec, win, m, tk)
                p = q
            ahead[i] = -1
        for t in range(nptr[i], nptr[i + 1]):  # the neighbours' bounds fall
            j = np.int64(nbr[t])
            if state[j] != 1:
                continue
            rec[j, 0] -= low[t]
            _fall(j, rec, win, m, tk)
    for i in range(n):  # the own points left: their keys at the stop
        if state[i] == 1 and tie[i] < nown:
            if not keys_left:
                prio[i] = -1.0
                continue
            cur = scale[i] * term_weight(i, nptr, nbr, state, term)
            if cover and cur > 0:
                cur *= min(rec[i, 2], _coverage(i, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, head, nxt,
                                            alt, altd2, rc2, gamma, lam, inv_r2, imp2, stats))
            prio[i] = cur


def relocate(P, near, kept, movable, tie, rcon2):
    """One restricted Lloyd step: each movable kept point moves to its Voronoi region's movable point nearest the centroid.

    Not when that takes a point of the region farther than max(current farthest,
    sqrt(rcon2)). Near-ties (relative 1e-9) keep k, then the lower ``tie``. Returns the new flags.
    """
    n = len(P)
    out = kept.copy()
    _relocate(P, near, movable, tie, rcon2, np.zeros(n), np.zeros((n, 3)), np.zeros(n), np.full(n, -1, dtype=np.int64),
              np.full(n, np.inf), np.zeros(n), out)
    return out


@njit(cache=True, nogil=True, _nrt=False)
def _relocate(P, near, movable, tie, rcon2, cnt, cen, far, best, bd, worst, out):
    n = len(P)
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
    for p in range(n):
        k = near[p]
        if k >= 0 and best[k] >= 0 and best[k] != k:
            b = best[k]
            worst[k] = max(worst[k], (P[p, 0] - P[b, 0]) ** 2 + (P[p, 1] - P[b, 1]) ** 2 + (P[p, 2] - P[b, 2]) ** 2)
    for k in range(n):
        b = best[k]
        if b >= 0 and b != k and worst[k] <= max(far[k], rcon2) * (1.0 + 1e-9):
            out[k] = 0
            out[b] = 1
