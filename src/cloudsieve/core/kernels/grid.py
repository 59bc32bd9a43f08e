"""Compiled kernels of the uniform grid the elimination searches (numba; private, inputs assumed valid).

Points are sorted by cell code (a Z-order code of the integer cell
coordinates, < 2^21 per axis) and, inside a cell, by coordinates; ``cell``
(n,) is the cell of each sorted point, ``cstart`` (C + 1,) the first point of
each cell, ``nstart``/``ncells`` the CSR list of the occupied cells among the
27 around each cell, in a fixed order. ``state`` (n,) uint8: 0 absent.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .order import radix_passes
from .threads import Chunks

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


# Not parallel=True (nor nearest_kept): measured on 2 cores (load ~7) on a 220,000-point cell, cell_codes took
# 1.1-4.1 ms parallel against 1.7-1.9 ms in one thread, nearest_kept 83-104 ms against 46-47 ms, and their
# compilation 0.3 s and 1.1 s more; a cell task runs on one core anyway, and a fork server that has run a
# parallel kernel cannot fork (GNU OpenMP), so the default rule's kernels can be warmed up there
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
    """``np.argsort(key, kind="stable")`` of non-negative int64 keys: an LSD radix sort by bytes, over the
    bytes the largest key uses (a cell's codes and keys are small: 2-3 passes). Written here because numpy's
    stable sort of int64 is a merge sort: 0.81 ms for the 16,359 codes of a 16,384-point cell, against
    0.14 ms here, of a grid built in 2.4 ms."""
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
    """Keys (C,) in the lexicographic order of the integer coordinates ``xyz`` (C >= 1, 3) for the sweep's
    sort: numbered in the cells' box (smaller than ``_lex_keys``' ``key``: fewer radix passes, the same
    order), or ``key`` itself when the box holds 2^62 cells or more."""
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
def _less(P, a, b):
    for j in range(3):
        if P[a, j] != P[b, j]:
            return P[a, j] < P[b, j]
    return a < b


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def _lex_keys(ukeys):
    """Integer coordinates (C, 3) of the cells of Z-order codes ``ukeys`` and their (x, y, z) keys (C,):
    x << 42 | y << 21 | z, in the lexicographic order of the coordinates."""
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
def _column_sweep(xyz, L, K):
    """CSR of the occupied cells among the 27 around each cell, in (dx, dy, dz) order: one sweep of the
    cells in (x, y, z) order (``L``, keys ``K`` sorted); the 3 cells dz = -1, 0, 1 of each of the 9 columns
    (dx, dy) around a cell are consecutive keys, found by a cursor per column that only moves forward (a
    column's keys rise with the cells'). Collected in sweep order, then copied to each cell's place."""
    C = len(K)
    cur = np.zeros(9, dtype=np.int64)
    tmp = np.empty(27 * C, dtype=np.int64)
    first = np.empty(C, dtype=np.int64)
    cnt = np.empty(C, dtype=np.int64)
    t = 0
    for u in range(C):
        c = L[u]
        x, y, z = xyz[c, 0], xyz[c, 1], xyz[c, 2]
        first[c] = t
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
        cnt[c] = t - first[c]
    nstart = np.zeros(C + 1, dtype=np.int64)
    for c in range(C):
        nstart[c + 1] = nstart[c] + cnt[c]
    out = np.empty(t, dtype=np.int64)
    for c in range(C):
        s = first[c]
        o = nstart[c]
        for j in range(cnt[c]):
            out[o + j] = tmp[s + j]
    return nstart, out


def cell_neighbours(ukeys):
    """CSR (nstart (C + 1,), ncells) of the occupied cells among the 27 around each cell (codes ``ukeys``,
    sorted), in (dx, dy, dz) order.

    A sweep in (x, y, z) order with a forward cursor per column
    (:func:`_column_sweep`), not 27 hash-table lookups a cell: 19.3 -> 6.7 ms
    for the 63,386 cells of a 138,000-point cell of the 10 M scan (the same
    lists). numpy's stable sort: the keys come in Z order, partly sorted.
    """
    xyz, key = _lex_keys(ukeys)
    L = argsort_keys(_sweep_keys(xyz, key) if len(ukeys) else key)
    return _column_sweep(xyz, L, key[L])


@njit(cache=True)
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


@njit(cache=True, nogil=True)
def nearest_kept(P, cell, cstart, nstart, ncells, kept, tie, rows):
    """Nearest kept point (kept != 0) of each point of ``rows`` (equal distances: lower ``tie``), -1 when
    none is in its 27 cells."""
    out = np.empty(len(rows), dtype=np.int64)
    none = np.int64(-1)  # not the literal -1: the elimination's signature of nearest, compiled once
    for u in range(len(rows)):
        out[u] = nearest(rows[u], none, P, cell, cstart, nstart, ncells, kept, tie)[0]
    return out


# A plain function, as .eliminate.eliminate: its allocations in numpy (compiled, they tripled the compile time:
# 1.2 s against 0.4 s), the work in _nearest_rows, on ranges of rows on threads
def nearest_rows(P, cell, cstart, nstart, ncells, rows, k, reach2, crowd, complete, threads=1, lo=None, h=np.inf):
    """The k nearest points (itself included) of each of ``rows`` in the 27 cells around it: squared distances
    (len(rows), k) ascending (equal ones: lower row first; +inf after the points there are), their rows (-1
    there), and each one's status: 0 sure (its k-th squared distance is below ``reach2``, which the 27 cells
    surely cover, or they hold every point: ``complete``), 1 not sure (points farther out may be nearer), 2 not
    searched: more than ``crowd`` points in its 27 cells (crowd < 0: never). A squared distance is summed as
    scipy's cKDTree sums it, ``(dx*dx + dy*dy) + dz*dz``. Each row's answer is its own: the same on any number
    of ``threads``. With the grid's corner ``lo`` and side ``h`` (:class:`~cloudsieve.core.cellgrid.CellGrid`),
    the cells farther from a row than its k-th distance so far are skipped (the same answers)."""
    d = np.full((len(rows), k), np.inf)
    idx = np.full((len(rows), k), -1, dtype=np.int64)
    status = np.zeros(len(rows), dtype=np.uint8)
    lo = np.zeros(3) if lo is None else lo
    with Chunks(threads) as chunks:
        chunks.map(lambda s, e: _nearest_rows(P, cell, cstart, nstart, ncells, rows[s:e], k, reach2, crowd, complete,
                                              d[s:e], idx[s:e], status[s:e], lo, h), len(rows))
    return d, idx, status


@njit(cache=True, nogil=True)
def store_sure(d, i, at, dd, ii, status, order):
    """The answers of :func:`nearest_rows` that are sure (``status`` 0) into rows ``at`` of the distances ``d``
    (square roots of ``dd``) and rows ``i`` (``order`` of theirs; -1 stays -1). numpy's masked copies and
    scatters of these (50,000, 9) arrays took 10-30 ms, in the serial start of an elimination."""
    k = dd.shape[1]
    for u in range(len(at)):
        if status[u] != 0:
            continue
        a = at[u]
        for t in range(k):
            d[a, t] = np.sqrt(dd[u, t])
            j = ii[u, t]
            i[a, t] = order[j] if j >= 0 else -1


@njit(cache=True, nogil=True)
def kth_others(d, i, q, mult, k):
    """The distance from each distinct row q[u] to its k-th nearest other row, from its k-NN (itself included)
    among the distinct rows (``d``, ``i`` of shape (len(q), kk), nearest first) and each distinct row's copies
    ``mult``: 0 when its own copies make k others, else the distance at which the others' copies, counted
    nearest first without itself (its first column in ``i``, else the last), reach the others still needed
    (none reach them: the nearest other's). numpy's masks, cumulative sums and argmaxes over the (50,000, 9)
    arrays took 5 ms."""
    kk = d.shape[1]
    out = np.empty(len(q))
    for u in range(len(q)):
        drop = kk - 1
        for t in range(kk):
            if i[u, t] == q[u]:
                drop = t
                break
        need = k - (mult[q[u]] - 1)
        if need <= 0:
            out[u] = 0.0
            continue
        cum = 0
        col = -1
        first = -1
        for t in range(kk):
            if t == drop:
                continue
            if first < 0:
                first = t
            cum += mult[i[u, t]]
            if cum >= need:
                col = t
                break
        out[u] = d[u, col if col >= 0 else first]
    return out


#: the gap from a row to a neighbouring cell is lowered by this many cell sides: (x - lo) - q h is computed
#: within about 3 * 2^-52 * 2^21 = 1.4e-9 sides (at most 2^21 cells an axis) and a cell's floor within 5e-10
SLACK = 1e-8


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _insert(d, idx, u, last, d2, j):
    """Insert (d2, j) in row u's ascending list (equal distances: lower row first); the last one drops."""
    q = last
    while q > 0 and (d[u, q - 1] > d2 or (d[u, q - 1] == d2 and idx[u, q - 1] > j)):
        d[u, q] = d[u, q - 1]
        idx[u, q] = idx[u, q - 1]
        q -= 1
    d[u, q] = d2
    idx[u, q] = j


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _floor(x, lo, h):
    """The grid coordinate of x along one axis (as :func:`cell_codes` computes it)."""
    return min(np.int64((x - lo) / h), np.int64(0x1FFFFF))


@njit(cache=True, nogil=True, _nrt=False)
def _nearest_rows(P, cell, cstart, nstart, ncells, rows, k, reach2, crowd, complete, d, idx, status, lo, h):
    """The search of :func:`nearest_rows`: a row's own cell first (its k-th distance falls soonest), then each
    other cell unless a lower bound of its distance (its gap on each axis, lowered by ``SLACK`` sides) is
    beyond the k-th distance so far: the k nearest by (distance, row) do not depend on the order the
    candidates come in. On a 50,000-point sample of a surface, 36-40 ms against 47-55 ms (one thread)."""
    nq = len(rows)
    last = k - 1
    prune = h < np.inf  # else one cell holds every row
    slack = SLACK * h if prune else 0.0
    for u in range(nq):
        p = rows[u]
        c = cell[p]
        if crowd >= 0:
            m = 0
            for t in range(nstart[c], nstart[c + 1]):
                m += cstart[ncells[t] + 1] - cstart[ncells[t]]
            if m > crowd:
                status[u] = 2
                continue
        x, y, z = P[p, 0], P[p, 1], P[p, 2]
        q0, q1, q2 = 0, 0, 0
        gl0, gl1, gl2, gu0, gu1, gu2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if prune:  # the gaps to the lower and upper faces of its cell, in the grid's frame
            q0, q1, q2 = _floor(x, lo[0], h), _floor(y, lo[1], h), _floor(z, lo[2], h)
            gl0 = max((x - lo[0]) - q0 * h - slack, 0.0)
            gl1 = max((y - lo[1]) - q1 * h - slack, 0.0)
            gl2 = max((z - lo[2]) - q2 * h - slack, 0.0)
            gu0 = max((q0 + 1) * h - (x - lo[0]) - slack, 0.0)
            gu1 = max((q1 + 1) * h - (y - lo[1]) - slack, 0.0)
            gu2 = max((q2 + 1) * h - (z - lo[2]) - slack, 0.0)
        worst = np.inf  # d[u, last]
        wrow = np.int64(-1)  # idx[u, last]
        for j in range(cstart[c], cstart[c + 1]):
            dx = P[j, 0] - x
            dy = P[j, 1] - y
            dz = P[j, 2] - z
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < worst or (d2 == worst and j < wrow):
                _insert(d, idx, u, last, d2, j)
                worst = d[u, last]
                wrow = idx[u, last]
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            if cc == c:
                continue
            f = cstart[cc]
            if prune:
                o0 = _floor(P[f, 0], lo[0], h) - q0
                o1 = _floor(P[f, 1], lo[1], h) - q1
                o2 = _floor(P[f, 2], lo[2], h) - q2
                g0 = gl0 if o0 < 0 else (gu0 if o0 > 0 else 0.0)
                g1 = gl1 if o1 < 0 else (gu1 if o1 > 0 else 0.0)
                g2 = gl2 if o2 < 0 else (gu2 if o2 > 0 else 0.0)
                if g0 * g0 + g1 * g1 + g2 * g2 > worst:
                    continue
            for j in range(f, cstart[cc + 1]):
                dx = P[j, 0] - x
                dy = P[j, 1] - y
                dz = P[j, 2] - z
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < worst or (d2 == worst and j < wrow):
                    _insert(d, idx, u, last, d2, j)
                    worst = d[u, last]
                    wrow = idx[u, last]
        if not complete and not worst < reach2:
            status[u] = 1
