"""Compiled kernels of the radius's k-NN on the elimination's grids (numba; private, inputs assumed valid).

:func:`nearest_rows` searches the 27 cells around rows of a
:class:`~cloudsieve.core.cellgrid.CellGrid` (grid arguments: :mod:`.grid`);
:func:`store_sure` and :func:`kth_others` give :mod:`cloudsieve.core.radius` its distances.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .threads import Chunks


# A plain function, as .eliminate.eliminate: allocations in numpy, the work in _nearest_rows on threads
def nearest_rows(P, cell, cstart, nstart, ncells, rows, k, reach2, crowd, complete, threads=1, lo=None, h=np.inf):
    """The k nearest points (itself included) of each of ``rows`` in the 27 cells around it.

    Returns squared distances (len(rows), k) ascending (ties: lower row; +inf past the
    points), their rows (-1 there), and a status: 0 sure (k-th below ``reach2`` or
    ``complete``), 1 not sure, 2 not searched (more than ``crowd`` points; crowd < 0:
    never). Sums as cKDTree's; independent of ``threads``. With ``lo`` and ``h``, cells
    beyond the k-th distance so far are skipped.
    """
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
    """Sure answers (``status`` 0) of :func:`nearest_rows` into rows ``at`` of ``d`` (sqrt of ``dd``) and ``i`` (through ``order``)."""
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
    """Distance from each distinct row q[u] to its k-th nearest other row, from its k-NN among distinct rows and copies ``mult``.

    0 when its own copies make k others; else where the others' copies, nearest first, reach the count.
    """
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


#: the gap from a row to a neighbouring cell is lowered by this many cell sides (rounding of (x - lo) - q h)
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


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _scan(P, a, b, x, y, z, d, idx, u, last, worst, wrow):
    """Rows [a, b) as candidates of row u's list at (x, y, z); returns its new k-th (squared distance, row)."""
    for j in range(a, b):
        dx = P[j, 0] - x
        dy = P[j, 1] - y
        dz = P[j, 2] - z
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < worst or (d2 == worst and j < wrow):
            _insert(d, idx, u, last, d2, j)
            worst = d[u, last]
            wrow = idx[u, last]
    return worst, wrow


@njit(cache=True, nogil=True, _nrt=False)
def _nearest_rows(P, cell, cstart, nstart, ncells, rows, k, reach2, crowd, complete, d, idx, status, lo, h):
    """The search of :func:`nearest_rows`: own cell first, then each cell whose lower-bound gap (less ``SLACK`` sides) is within the k-th distance so far."""
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
        worst, wrow = _scan(P, cstart[c], cstart[c + 1], x, y, z, d, idx, u, last, worst, wrow)
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
            worst, wrow = _scan(P, f, cstart[cc + 1], x, y, z, d, idx, u, last, worst, wrow)
        if not complete and not worst < reach2:
            status[u] = 1
