"""Compiled kernels of the k nearest centres of points (numba; private: inputs are assumed valid).

Centres are filed in a uniform grid (side h, :func:`grid_cells`). A query searches
rings of cells (:func:`ring_search`) or, for many points, reads its cell's list in
a finer grid (:func:`cell_candidates`: every centre within D_k of the cell, D_k the
k-th smallest distance from a centre to the cell's farthest corner). Both are
exact: squared distances are cKDTree's and bounds carry a rounding slack
(``margin``, and relative 1e-9); only the order among equal distances may differ,
reported per row (``tie``).

Grid tuples (made by :mod:`cloudsieve.core.centres`):
``ring = (Cg, gid, start, lo, h, dims, margin)``: centres in cell order (c, p),
their indices, cell CSR offsets, origin (3,), side, cells per axis (3,), slack;
``lists = (flo, s, fdims, cellpos, lstart, lids, C)``: fine grid origin, side, cells
per axis, each fine cell's list position (-1: none; length 0: no lists), list CSR
offsets, listed centre indices (int32) and the centres.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["sqdist", "grid_cells", "fine_cells", "cell_candidates", "ring_search", "nearest_centres"]


@njit(cache=True, nogil=True, inline="always")
def sqdist(X, i, C, t):
    """Squared distance of X[i] and C[t], summed over the coordinates in order from 0."""
    d2 = 0.0
    for j in range(X.shape[1]):
        diff = X[i, j] - C[t, j]
        d2 += diff * diff
    return d2


@njit(cache=True, nogil=True, inline="always")
def _cell(x, lo, h, g):
    v = math.floor((x - lo) / h)
    if v < 0.0:
        return 0
    if v > g - 1:
        return g - 1
    return int(v)


@njit(cache=True, nogil=True, inline="always")
def _coord(X, i, j):
    return X[i, j] if j < X.shape[1] else 0.0


@njit(cache=True, nogil=True)
def grid_cells(P, lo, h, dims):
    """Cell (n,) int64 of each row of P (n, p): (ix * dims[1] + iy) * dims[2] + iz.

    Grid of origin lo (3,), side h, dims (3,) cells on the first three coordinates
    (fewer: one cell on missing axes); outside rows go to the nearest border cell.
    """
    out = np.empty(P.shape[0], dtype=np.int64)
    for i in range(P.shape[0]):
        ix = _cell(_coord(P, i, 0), lo[0], h, dims[0])
        iy = _cell(_coord(P, i, 1), lo[1], h, dims[1])
        iz = _cell(_coord(P, i, 2), lo[2], h, dims[2])
        out[i] = (ix * dims[1] + iy) * dims[2] + iz
    return out


@njit(cache=True, nogil=True, inline="always")
def _insert(bd, bi, cnt, k, d2, t):
    """Insert (d2, t) into the ascending bd/bi of cnt <= k entries (after equal distances); returns the new count."""
    if cnt < k:
        q = cnt
        cnt += 1
    elif d2 < bd[k - 1]:
        q = k - 1
    else:
        return cnt
    while q > 0 and bd[q - 1] > d2:
        bd[q] = bd[q - 1]
        bi[q] = bi[q - 1]
        q -= 1
    bd[q] = d2
    bi[q] = t
    return cnt


@njit(cache=True, nogil=True, _nrt=False)
def ring_search(X, i, ring, k, bd, bi):
    """The k nearest centres of X[i] by rings of cells: squared distances bd (k,) ascending, indices bi (k,)."""
    Cg, gid, start, lo, h, dims, margin = ring
    gx, gy, gz = dims[0], dims[1], dims[2]
    x0, x1, x2 = _coord(X, i, 0), _coord(X, i, 1), _coord(X, i, 2)
    cx, cy, cz = _cell(x0, lo[0], h, gx), _cell(x1, lo[1], h, gy), _cell(x2, lo[2], h, gz)
    cnt = 0
    r = 0
    while True:
        for ax in range(max(cx - r, 0), min(cx + r, gx - 1) + 1):
            ex = abs(ax - cx) == r
            for ay in range(max(cy - r, 0), min(cy + r, gy - 1) + 1):
                full = ex or abs(ay - cy) == r
                zb = min(cz + r, gz - 1)
                az = max(cz - r, 0) if full else (cz - r if cz - r >= 0 else cz + r)
                while az <= zb:  # the whole column, or only the ring's two z faces
                    g = (ax * gy + ay) * gz + az
                    for t in range(start[g], start[g + 1]):
                        cnt = _insert(bd, bi, cnt, k, sqdist(X, i, Cg, t), t)
                    az = az + 1 if full or az == cz + r else cz + r
        lb = np.inf  # the distance to the cells not visited yet
        if cx - r > 0:
            lb = min(lb, x0 - (lo[0] + (cx - r) * h))
        if cx + r < gx - 1:
            lb = min(lb, (lo[0] + (cx + r + 1) * h) - x0)
        if cy - r > 0:
            lb = min(lb, x1 - (lo[1] + (cy - r) * h))
        if cy + r < gy - 1:
            lb = min(lb, (lo[1] + (cy + r + 1) * h) - x1)
        if cz - r > 0:
            lb = min(lb, x2 - (lo[2] + (cz - r) * h))
        if cz + r < gz - 1:
            lb = min(lb, (lo[2] + (cz + r + 1) * h) - x2)
        if lb == np.inf:  # every cell visited
            break
        if cnt == k:
            s = (lb - margin) * (1.0 - 1e-9)
            if s > 0.0 and s * s > bd[k - 1]:
                break
        r += 1
    for j in range(k):
        bi[j] = gid[bi[j]]


@njit(cache=True, nogil=True, inline="always")
def _fine_cell(X, i, flo, s, fdims):
    """The fine cell of X[i], or -1 outside the fine grid."""
    g = 0
    for j in range(3):
        v = math.floor((_coord(X, i, j) - flo[j]) / s)
        if not (0.0 <= v < fdims[j]):
            return -1
        g = g * fdims[j] + int(v)
    return g


@njit(cache=True, nogil=True)
def fine_cells(X, rows, r0, r1, flo, s, fdims, occupied):
    """occupied[g] = 1 for the fine cell g of each point X[rows[r0:r1]] inside the grid."""
    for r in range(r0, r1):
        g = _fine_cell(X, rows[r], flo, s, fdims)
        if g >= 0:
            occupied[g] = 1


@njit(cache=True, nogil=True)
def cell_candidates(cells, a, b, ring, flo, s, fdims, k):
    """The candidate lists of the fine cells cells[a:b] (see the module docstring).

    Returns counts (b - a,) int64 and ids (counts.sum(),) int64: the lists in turn,
    each by increasing distance to its cell.
    """
    Cg, gid, start, lo, h, dims, margin = ring
    nc = Cg.shape[0]
    p = min(Cg.shape[1], 3)
    gx, gy, gz = dims[0], dims[1], dims[2]
    counts = np.zeros(b - a, dtype=np.int64)
    out = np.empty(max(16, (b - a) * 2 * k), dtype=np.int64)
    used = 0
    tid = np.empty(nc, dtype=np.int64)
    tmin = np.empty(nc)
    kmax = np.empty(k)
    kpos = np.empty(k, dtype=np.int64)
    bl = np.zeros(3)
    bh = np.zeros(3)
    for q in range(a, b):
        g = cells[q]
        f2 = g % fdims[2]
        f1 = (g // fdims[2]) % fdims[1]
        f0 = g // (fdims[2] * fdims[1])
        f = (f0, f1, f2)
        for j in range(p):
            bl[j] = flo[j] + f[j] * s - margin
            bh[j] = flo[j] + (f[j] + 1) * s + margin
        cx = _cell(0.5 * (bl[0] + bh[0]), lo[0], h, gx)
        cy = _cell(0.5 * (bl[1] + bh[1]), lo[1], h, gy)
        cz = _cell(0.5 * (bl[2] + bh[2]), lo[2], h, gz)
        nv = 0
        nk = 0
        r = 0
        while True:
            for ax in range(max(cx - r, 0), min(cx + r, gx - 1) + 1):
                ex = abs(ax - cx) == r
                for ay in range(max(cy - r, 0), min(cy + r, gy - 1) + 1):
                    full = ex or abs(ay - cy) == r
                    zb = min(cz + r, gz - 1)
                    az = max(cz - r, 0) if full else (cz - r if cz - r >= 0 else cz + r)
                    while az <= zb:
                        cg = (ax * gy + ay) * gz + az
                        for t in range(start[cg], start[cg + 1]):
                            mn = 0.0
                            mx = 0.0
                            for j in range(p):
                                c = Cg[t, j]
                                lo_gap = bl[j] - c
                                hi_gap = c - bh[j]
                                m = max(lo_gap, hi_gap, 0.0)
                                mn += m * m
                                w = max(abs(c - bl[j]), abs(c - bh[j]))
                                mx += w * w
                            tid[nv] = t
                            tmin[nv] = mn
                            nv += 1
                            nk = _insert(kmax, kpos, nk, k, mx, t)
                        az = az + 1 if full or az == cz + r else cz + r
            lb = np.inf  # the distance from B to the coarse cells not visited yet
            if cx - r > 0:
                lb = min(lb, bl[0] - (lo[0] + (cx - r) * h))
            if cx + r < gx - 1:
                lb = min(lb, (lo[0] + (cx + r + 1) * h) - bh[0])
            if cy - r > 0:
                lb = min(lb, bl[1] - (lo[1] + (cy - r) * h))
            if cy + r < gy - 1:
                lb = min(lb, (lo[1] + (cy + r + 1) * h) - bh[1])
            if cz - r > 0:
                lb = min(lb, bl[2] - (lo[2] + (cz - r) * h))
            if cz + r < gz - 1:
                lb = min(lb, (lo[2] + (cz + r + 1) * h) - bh[2])
            if lb == np.inf:
                break
            if nk == k and lb * (1.0 - 1e-9) - 2.0 * margin > math.sqrt(kmax[k - 1]) * (1.0 + 1e-9):
                break
            r += 1
        thr = math.sqrt(kmax[k - 1]) * (1.0 + 1e-9) + margin
        thr2 = thr * thr
        m0 = used
        for v in range(nv):
            if tmin[v] <= thr2:
                if used == len(out):
                    grown = np.empty(2 * len(out), dtype=np.int64)
                    grown[:used] = out[:used]
                    out = grown
                # insertion by distance to the cell (stable), nearest first
                w = used
                while w > m0 and tmin[out[w - 1]] > tmin[v]:
                    out[w] = out[w - 1]
                    w -= 1
                out[w] = v
                used += 1
        for w in range(m0, used):
            out[w] = gid[tid[out[w]]]
        counts[q - a] = used - m0
    return counts, out[:used].copy()


@njit(cache=True, nogil=True, inline="always")
def knn_row(X, i, ring, lists, k, bd, bi):
    """The k nearest centres of X[i] into bd, bi (fine cell's list, else rings); returns 1 when two distances tie."""
    flo, s, fdims, cellpos, lstart, lids, lC = lists  # lC: the centres (c, p)
    pos = -1
    if len(cellpos):
        g = _fine_cell(X, i, flo, s, fdims)
        if g >= 0:
            pos = cellpos[g]
    if pos >= 0:
        cnt = 0
        for t in range(lstart[pos], lstart[pos + 1]):
            g = lids[t]
            cnt = _insert(bd, bi, cnt, k, sqdist(X, i, lC, g), g)
    else:
        ring_search(X, i, ring, k, bd, bi)
    tie = 0
    for j in range(1, k):
        if bd[j] == bd[j - 1]:
            tie = 1
    return tie


@njit(cache=True, nogil=True)
def nearest_centres(X, rows, r0, r1, ring, lists, k, out_d, out_i, tie):
    """The k nearest centres of X[rows[r0:r1]] (:func:`knn_row`) at positions r0..r1-1.

    Writes out_d (distances ascending), out_i (indices), both (m, k), and tie (m,) (1: two distances equal).
    """
    bd = np.empty(k)
    bi = np.empty(k, dtype=np.int64)
    for r in range(r0, r1):
        tie[r] = knn_row(X, rows[r], ring, lists, k, bd, bi)
        for j in range(k):
            out_d[r, j] = math.sqrt(bd[j])
            out_i[r, j] = bi[j]
