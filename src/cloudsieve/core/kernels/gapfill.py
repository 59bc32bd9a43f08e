"""Compiled kernel of the gap bound's fill (numba; private): a greedy cover at distance D.

:func:`greedy_cover` takes the points left farther than D from the kept set,
in their order of priority, and adds each one that no point added before it
lies within D of. Points within D of each other lie in neighbouring cells of
a grid of cell size D, so each point looks at the added points of 27 cells.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _find(u, x, y, z):
    """The row of (x, y, z) in the lexicographically sorted rows *u* (m, 3), or -1."""
    lo, hi = 0, len(u)
    while lo < hi:
        mid = (lo + hi) // 2
        a, b, c = u[mid, 0], u[mid, 1], u[mid, 2]
        if a < x or (a == x and (b < y or (b == y and c < z))):
            lo = mid + 1
        else:
            hi = mid
    if lo < len(u) and u[lo, 0] == x and u[lo, 1] == y and u[lo, 2] == z:
        return lo
    return -1


@njit(cache=True)
def greedy_cover(P, q, cell, u, gap):
    """Which rows of *P* (m, 3), in order, are added: those with no earlier added row within *gap*.

    *q* (m, 3): each row's grid cell (cell size *gap*); *u* (c, 3): the
    occupied cells, sorted lexicographically; *cell* (m,): each row's cell in
    *u*. Distances as scipy's k-d tree computes them (the root of the sum of
    the squared differences, x, y, z).
    """
    m = len(P)
    head = np.full(len(u), -1, dtype=np.int64)
    nxt = np.full(m, -1, dtype=np.int64)
    added = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        covered = False
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    c = _find(u, q[i, 0] + dx, q[i, 1] + dy, q[i, 2] + dz)
                    j = head[c] if c >= 0 else -1
                    while j >= 0:
                        e = (P[i, 0] - P[j, 0]) ** 2 + (P[i, 1] - P[j, 1]) ** 2 + (P[i, 2] - P[j, 2]) ** 2
                        if np.sqrt(e) <= gap:
                            covered = True
                            break
                        j = nxt[j]
                    if covered:
                        break
                if covered:
                    break
            if covered:
                break
        if not covered:
            added[i] = True
            nxt[i] = head[cell[i]]
            head[cell[i]] = i
    return added
