"""Compiled kernels of the uniform grid the elimination searches (numba; private, inputs assumed valid).

Points are sorted by cell code (a Z-order code of the integer cell
coordinates, < 2^21 per axis) and, inside a cell, by coordinates; ``cell``
(n,) is the cell of each sorted point, ``cstart`` (C + 1,) the first point of
each cell, ``nstart``/``ncells`` the CSR list of the occupied cells among the
27 around each cell, in a fixed order. ``state`` (n,) uint8: 0 absent.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_M1 = np.int64(0x1F00000000FFFF)
_M2 = np.int64(0x1F0000FF0000FF)
_M3 = np.int64(0x100F00F00F00F00F)
_M4 = np.int64(0x10C30C30C30C30C3)
_M5 = np.int64(0x1249249249249249)


@njit(cache=True)
def _spread(v):
    v &= 0x1FFFFF
    v = (v | (v << 32)) & _M1
    v = (v | (v << 16)) & _M2
    v = (v | (v << 8)) & _M3
    v = (v | (v << 4)) & _M4
    v = (v | (v << 2)) & _M5
    return v


@njit(cache=True, _nrt=False)
def _compact(v):
    v &= _M5
    v = (v | (v >> 2)) & _M4
    v = (v | (v >> 4)) & _M3
    v = (v | (v >> 8)) & _M2
    v = (v | (v >> 16)) & _M1
    v = (v | (v >> 32)) & 0x1FFFFF
    return v


@njit(cache=True, parallel=True)
def cell_codes(P, lo, h):
    """Z-order code (n,) int64 of each point's grid cell (cells of size h from lo, < 2^21 per axis)."""
    n = len(P)
    out = np.empty(n, dtype=np.int64)
    for i in prange(n):
        c = np.int64(0)
        for j in range(3):
            q = min(np.int64((P[i, j] - lo[j]) / h), np.int64(0x1FFFFF))
            c |= _spread(q) << j
        out[i] = c
    return out


@njit(cache=True, _nrt=False)
def _less(P, a, b):
    for j in range(3):
        if P[a, j] != P[b, j]:
            return P[a, j] < P[b, j]
    return a < b


@njit(cache=True)
def sort_cells(P, codes, order, longest):
    """Inside each run of equal codes in ``order`` of at most ``longest`` points, sort by coordinates then
    index (insertion sort, in place); longer runs are left as they are."""
    n = len(order)
    s = 0
    while s < n:
        e = s + 1
        while e < n and codes[order[e]] == codes[order[s]]:
            e += 1
        if e - s > longest:
            s = e
            continue
        for i in range(s + 1, e):
            v = order[i]
            j = i - 1
            while j >= s and _less(P, v, order[j]):
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = v
        s = e


@njit(cache=True)
def cell_neighbours(ukeys):
    """CSR (nstart (C + 1,), ncells) of the occupied cells among the 27 around each cell (codes ``ukeys``, sorted)."""
    C = len(ukeys)
    size = 1
    while size < 2 * C + 2:
        size *= 2
    table = np.full(size, -1, dtype=np.int64)
    mask = np.uint64(size - 1)
    mult = np.uint64(0x9E3779B97F4A7C15)
    for c in range(C):
        s = np.int64((np.uint64(ukeys[c]) * mult) >> np.uint64(20)) & np.int64(size - 1)
        while table[s] >= 0:
            s = (s + 1) & np.int64(size - 1)
        table[s] = c
    nstart = np.zeros(C + 1, dtype=np.int64)
    out = np.empty(27 * C, dtype=np.int64)
    t = 0
    for c in range(C):
        q0 = _compact(ukeys[c])
        q1 = _compact(ukeys[c] >> 1)
        q2 = _compact(ukeys[c] >> 2)
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    a, b, d = q0 + dx, q1 + dy, q2 + dz
                    if a < 0 or b < 0 or d < 0 or a > 0x1FFFFF or b > 0x1FFFFF or d > 0x1FFFFF:
                        continue
                    key = _spread(a) | (_spread(b) << 1) | (_spread(d) << 2)
                    s = np.int64((np.uint64(key) * mult) >> np.uint64(20)) & np.int64(mask)
                    while table[s] >= 0:
                        if ukeys[table[s]] == key:
                            out[t] = table[s]
                            t += 1
                            break
                        s = (s + 1) & np.int64(mask)
        nstart[c + 1] = t
    return nstart, out[:t].copy()


@njit(cache=True, inline="always")
def nearest(p, x, P, cell, cstart, nstart, ncells, state, tie):
    """Nearest alive point to p other than x (equal distances: lower ``tie``), squared distance; (-1, inf)
    if none in the 27 cells around p."""
    c = cell[p]
    best = -1
    bd = np.inf
    for t in range(nstart[c], nstart[c + 1]):
        cc = ncells[t]
        for j in range(cstart[cc], cstart[cc + 1]):
            if j == x or state[j] == 0:
                continue
            dx = P[j, 0] - P[p, 0]
            dy = P[j, 1] - P[p, 1]
            dz = P[j, 2] - P[p, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < bd or (d2 == bd and tie[j] < tie[best]):
                bd = d2
                best = j
    return best, bd


@njit(cache=True, parallel=True)
def nearest_kept(P, cell, cstart, nstart, ncells, kept, tie, rows):
    """Nearest kept point (kept != 0) of each point of ``rows`` (equal distances: lower ``tie``), -1 when
    none is in its 27 cells."""
    out = np.empty(len(rows), dtype=np.int64)
    for u in prange(len(rows)):
        out[u] = nearest(rows[u], -1, P, cell, cstart, nstart, ncells, kept, tie)[0]
    return out
