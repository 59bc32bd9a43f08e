"""Compiled kernels of the uniform grid the elimination searches (numba; private, inputs assumed valid).

Points sorted by Z-order cell code (< 2^21 cells per axis), inside a cell by
coordinates; ``cell`` (n,) each point's cell, ``cstart`` (C + 1,) each cell's first
point, ``nstart``/``ncells`` the CSR of occupied cells among the 27 around each.
``state`` (n,) uint8: 0 absent.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .order import radix_passes

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


# Not parallel=True: no faster on a cell, slower to compile, and a fork server that ran a parallel
# kernel cannot fork (GNU OpenMP)
@njit(cache=True, nogil=True)
def cell_codes(P, lo, h):
    """Z-order code (n,) int64 of each point's grid cell (cells of size h from lo, < 2^21 per axis)."""
    n = len(P)
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = np.int64(0)
        for j in range(3):
            q = min(np.int64((P[i, j] - lo[j]) / h), np.int64(0x1FFFFF))
            c |= _spread(q) << j
        out[i] = c
    return out


@njit(cache=True, nogil=True)
def argsort_keys(key):
    """``np.argsort(key, kind="stable")`` of non-negative int64 keys by an LSD byte radix sort (numpy's is a slower merge sort)."""
    n = len(key)
    top = np.int64(0)
    for i in range(n):
        top = max(top, key[i])
    passes = 0
    while top > 0:
        passes += 1
        top >>= 8
    u = key.copy().view(np.uint64)  # non-negative: the same order as unsigned integers
    hist = np.zeros((max(passes, 1), 256), np.int64)
    for i in range(n):
        for p in range(passes):
            hist[p, (u[i] >> np.uint64(8 * p)) & np.uint64(255)] += 1
    return radix_passes(u, hist, passes)


@njit(cache=True, nogil=True)
def _sweep_keys(xyz, key):
    """Keys (C,) in lexicographic order of integer coordinates ``xyz`` (C, 3), numbered in the cells' box (or ``key`` if too large)."""
    C = len(xyz)
    lo = xyz[0].copy()
    hi = xyz[0].copy()
    for c in range(C):
        for j in range(3):
            lo[j] = min(lo[j], xyz[c, j])
            hi[j] = max(hi[j], xyz[c, j])
    ny = hi[1] - lo[1] + 1
    nz = hi[2] - lo[2] + 1
    if hi[0] - lo[0] + 1 > (np.int64(1) << 62) // (ny * nz):  # ny * nz <= 2^42: no overflow
        return key
    out = np.empty(C, dtype=np.int64)
    for c in range(C):
        out[c] = ((xyz[c, 0] - lo[0]) * ny + (xyz[c, 1] - lo[1])) * nz + (xyz[c, 2] - lo[2])
    return out


@njit(cache=True, _nrt=False)
def _less(Q, order, i, v, q0, q1, q2):
    """Whether row (q0, q1, q2) of index v sorts before row i of Q (index order[i]): coordinates, then index."""
    if q0 != Q[i, 0]:
        return q0 < Q[i, 0]
    if q1 != Q[i, 1]:
        return q1 < Q[i, 1]
    if q2 != Q[i, 2]:
        return q2 < Q[i, 2]
    return v < order[i]


@njit(cache=True, nogil=True)
def sort_cells(Q, cstart, order, longest):
    """Insertion-sort *Q* (n, 3) rows and ``order`` in place by coordinates then index, within runs of <= ``longest`` rows.

    Longer runs are left as they are.
    """
    for c in range(len(cstart) - 1):
        s, e = cstart[c], cstart[c + 1]
        if e - s > longest:
            continue
        for i in range(s + 1, e):
            v = order[i]
            q0, q1, q2 = Q[i, 0], Q[i, 1], Q[i, 2]
            j = i - 1
            while j >= s and _less(Q, order, j, v, q0, q1, q2):
                order[j + 1] = order[j]
                Q[j + 1, 0], Q[j + 1, 1], Q[j + 1, 2] = Q[j, 0], Q[j, 1], Q[j, 2]
                j -= 1
            order[j + 1] = v
            Q[j + 1, 0], Q[j + 1, 1], Q[j + 1, 2] = q0, q1, q2


@njit(cache=True, nogil=True)
def _lex_keys(ukeys):
    """Integer coordinates (C, 3) of Z-order codes ``ukeys`` and keys (C,) x << 42 | y << 21 | z."""
    C = len(ukeys)
    xyz = np.empty((C, 3), dtype=np.int64)
    key = np.empty(C, dtype=np.int64)
    for c in range(C):
        x = _compact(ukeys[c])
        y = _compact(ukeys[c] >> 1)
        z = _compact(ukeys[c] >> 2)
        xyz[c, 0] = x
        xyz[c, 1] = y
        xyz[c, 2] = z
        key[c] = (x << 42) | (y << 21) | z
    return xyz, key


@njit(cache=True, nogil=True)
def _column_sweep(L, K):
    """CSR of occupied cells among the 27 around each, in (dx, dy, dz) order, by one sweep in (x, y, z) order.

    Each of the 9 columns around a cell is three consecutive keys, found by a forward
    cursor per column; results are written scattered, reads stay in order.
    """
    C = len(K)
    cur = np.zeros(9, dtype=np.int64)
    tmp = np.empty(27 * C, dtype=np.int64)
    nstart = np.zeros(C + 1, dtype=np.int64)
    t = 0
    for u in range(C):
        x, y, z = K[u] >> 42, (K[u] >> 21) & 0x1FFFFF, K[u] & 0x1FFFFF
        t0 = t
        col = 0
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                a, b = x + dx, y + dy
                if a >= 0 and b >= 0 and a <= 0x1FFFFF and b <= 0x1FFFFF:
                    base = (a << 42) | (b << 21)
                    lo = base | max(z - 1, 0)
                    hi = base | min(z + 1, 0x1FFFFF)
                    k = cur[col]
                    while k < C and K[k] < lo:
                        k += 1
                    cur[col] = k
                    while k < C and K[k] <= hi:
                        tmp[t] = L[k]
                        t += 1
                        k += 1
                col += 1
        nstart[L[u] + 1] = t - t0
    for c in range(C):
        nstart[c + 1] += nstart[c]
    out = np.empty(t, dtype=np.int64)
    s = 0
    for u in range(C):
        o, m = nstart[L[u]], nstart[L[u] + 1] - nstart[L[u]]
        for j in range(m):
            out[o + j] = tmp[s + j]
        s += m
    return nstart, out


def cell_neighbours(ukeys):
    """CSR (nstart (C + 1,), ncells) of occupied cells among the 27 around each (codes ``ukeys`` sorted), by :func:`_column_sweep`."""
    xyz, key = _lex_keys(ukeys)
    L = argsort_keys(_sweep_keys(xyz, key) if len(ukeys) else key)
    return _column_sweep(L, key[L])


@njit(cache=True, nogil=True)
def code_runs(codes, order):
    """Runs of equal ``codes[order]``: run of each row (n,), first row of each run plus n (C + 1,), run codes (C,)."""
    n = len(order)
    cell = np.empty(n, dtype=np.int64)
    runs = 0
    for i in range(n):
        if i == 0 or codes[order[i]] != codes[order[i - 1]]:
            runs += 1
        cell[i] = runs - 1
    cstart = np.empty(runs + 1, dtype=np.int64)
    ukeys = np.empty(runs, dtype=np.int64)
    for i in range(n):
        if i == 0 or cell[i] != cell[i - 1]:
            cstart[cell[i]] = i
            ukeys[cell[i]] = codes[order[i]]
    cstart[runs] = n
    return cell, cstart, ukeys


@njit(cache=True, nogil=True)
def copy_runs(P, cell):
    """Rows of *P* (n, 3) equal to the row before in the same cell, and the first row of each row's group (n,)."""
    n = len(P)
    copy = np.zeros(n, dtype=np.bool_)
    lead = np.empty(n, dtype=np.int64)
    for i in range(n):
        if i > 0 and cell[i] == cell[i - 1] and P[i, 0] == P[i - 1, 0] and P[i, 1] == P[i - 1, 1] \
                and P[i, 2] == P[i - 1, 2]:
            copy[i] = True
            lead[i] = lead[i - 1]
        else:
            lead[i] = i
    return copy, lead


@njit(cache=True)
def nearest(p, x, P, cell, cstart, nstart, ncells, state, tie):
    """Nearest alive point to p other than x (ties: lower ``tie``) and its squared distance; (-1, inf) if none in the 27 cells."""
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


@njit(cache=True, nogil=True)
def nearest_kept(P, cell, cstart, nstart, ncells, kept, tie, rows):
    """Nearest kept point of each of ``rows`` (ties: lower ``tie``), -1 when none in its 27 cells."""
    out = np.empty(len(rows), dtype=np.int64)
    none = np.int64(-1)  # not the literal -1: the elimination's signature of nearest, compiled once
    for u in range(len(rows)):
        out[u] = nearest(rows[u], none, P, cell, cstart, nstart, ncells, kept, tie)[0]
    return out
