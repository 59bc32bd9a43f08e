"""Compiled kernel of the packing counts (numba; private, inputs assumed valid).

Grid arguments as in :mod:`.grid`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def packing_counts(P, cell, cstart, nstart, ncells, skip, r2):
    """Sizes of greedy packings at the radii sqrt(r2) (increasing, at most 8), in one pass.

    Points are visited in grid order; a point joins packing k when no point
    already in it is closer than sqrt(r2[k]). Rows with ``skip`` join none.
    Each distance is computed once for every radius. Returns counts (L,).
    """
    n = len(P)
    L = len(r2)
    full = (1 << L) - 1
    mask = np.zeros(n, dtype=np.uint8)
    counts = np.zeros(L, dtype=np.int64)
    for i in range(n):
        if skip[i]:
            continue
        blocked = 0
        c = cell[i]
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            for j in range(cstart[cc], cstart[cc + 1]):
                m = mask[j] & ~blocked
                if m == 0:
                    continue
                dx = P[j, 0] - P[i, 0]
                dy = P[j, 1] - P[i, 1]
                dz = P[j, 2] - P[i, 2]
                d2 = dx * dx + dy * dy + dz * dz
                for k in range(L):  # within radius k, so within every larger one
                    if d2 < r2[k]:
                        blocked |= m & (full << k)
                        break
            if blocked == full:
                break
        free = full & ~blocked
        mask[i] = free
        for k in range(L):
            counts[k] += (free >> k) & 1
    return counts


@njit(cache=True, nogil=True)
def packing_from_lists(P, nptr, nbr, join, r2):
    """:func:`packing_counts` of the rows with ``join`` != 0 over the neighbour lists of :mod:`.neighbours`
    (every pair closer than the largest radius listed): the same packings in the grid's order, without a
    walk of the grid."""
    n = len(P)
    L = len(r2)
    full = (1 << L) - 1
    mask = np.zeros(n, dtype=np.uint8)
    counts = np.zeros(L, dtype=np.int64)
    for i in range(n):
        if join[i] == 0:
            continue
        blocked = 0
        for t in range(nptr[i], nptr[i + 1]):
            j = nbr[t]
            m = mask[j] & ~blocked
            if m == 0:
                continue
            dx = P[j, 0] - P[i, 0]
            dy = P[j, 1] - P[i, 1]
            dz = P[j, 2] - P[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            for k in range(L):
                if d2 < r2[k]:
                    blocked |= m & (full << k)
                    break
            if blocked == full:
                break
        free = full & ~blocked
        mask[i] = free
        for k in range(L):
            counts[k] += (free >> k) & 1
    return counts
