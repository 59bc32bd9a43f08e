"""Compiled kernels of the in-memory cells of ``eliminate`` (numba; private, inputs assumed valid).

numpy takes a fancy-indexed copy of the rows, a partition and two boolean
masks per cut; one histogram pass finds the median's bin instead, and the
rows are split here (together a third faster than numpy's). The
cut moves the points with their rows (:func:`median_cut`), so the cells'
points come out in cell order, each cell's a contiguous block.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def band_rows(Q, box, margin):
    """The positions of the points ``Q`` of one cell (box ``box`` (2, 3)) within ``margin`` of a face of its
    box, in their order: the points a neighbour's halo may hold."""
    out = np.empty(len(Q), dtype=np.int64)
    k = 0
    for t in range(len(Q)):
        near = False
        for j in range(3):
            near |= (Q[t, j] < box[0, j] + margin) | (Q[t, j] > box[1, j] - margin)
        out[k] = t
        k += near
    return out[:k].copy()


@njit(cache=True, nogil=True)
def halo_rows(P, band, bstart, cells, lo, hi):
    """The rows of the bands of ``cells`` (cell c's: ``band[bstart[c]:bstart[c + 1]]``) inside the box [lo,
    hi] (closed), cell after cell, each band in its order. numpy took a gathered copy and three boolean
    arrays a neighbour: 2.8% of a 1 M-point elimination's time."""
    m = 0
    for c in cells:
        m += bstart[c + 1] - bstart[c]
    out = np.empty(m, dtype=np.int64)
    k = 0
    for c in cells:
        for t in range(bstart[c], bstart[c + 1]):
            i = band[t]
            inside = True
            for j in range(3):
                inside &= (P[i, j] >= lo[j]) & (P[i, j] <= hi[j])
            out[k] = i
            k += inside
    return out[:k].copy()


def median_cut(Q, idx, axis, lo, hi, vals, tmp, tmpq, counts):
    """Cut rows ``idx`` with their points ``Q`` (``Q[t]`` the point of ``idx[t]``) at the median value v of
    coordinate ``axis`` (in [lo, hi]): the rows below v first, then the others, each in their order (when none
    is below v, those at v first), written into ``tmp`` (the rows) and ``tmpq`` (their points); ``idx`` and
    ``Q`` are left as they are (the caller's next cut reads the halves where they were written). Returns (v,
    position of the first row of the second part: 0 or len(idx) when no cut exists).

    v is the exact (m // 2)-th smallest value, as a partition of all of them gives it, found in three
    passes instead: a histogram of the values over ``len(counts)`` bins of [lo, hi] (the bin of a value
    never decreases with it), the values of the bin holding that rank, a partition of those few (numpy's:
    numba's ``np.partition`` and array slicing take ten times as long to compile as plain loops). The points
    move with their rows, so that every pass reads them in order: read through ``idx`` from the input's
    order, a cut takes half as long again.
    ``vals`` is scratch of at least len(idx) (rows)."""
    few, below = _median_bin(Q, axis, lo, hi, vals, counts)
    v = float(np.partition(few, len(idx) // 2 - below)[len(idx) // 2 - below])
    return v, _cut_at(idx, Q, vals, few, below, v, tmp, tmpq)


@njit(cache=True, nogil=True)
def _median_bin(Q, axis, lo, hi, vals, counts):
    """The values of coordinate ``axis`` of points ``Q`` into ``vals``; those of the histogram bin holding
    rank len(Q) // 2, and the number of values in the bins below it."""
    m = len(Q)
    nb = len(counts)
    for b in range(nb):
        counts[b] = 0
    scale = nb / (hi - lo) if hi > lo else 0.0
    for t in range(m):
        x = Q[t, axis]
        vals[t] = x
        counts[min(nb - 1, int((x - lo) * scale))] += 1
    k = m // 2
    below = 0
    b = 0
    while below + counts[b] <= k:
        below += counts[b]
        b += 1
    few = np.empty(counts[b])
    f = 0
    for t in range(m):
        if min(nb - 1, int((vals[t] - lo) * scale)) == b:
            few[f] = vals[t]
            f += 1
    return few, below


@njit(cache=True, nogil=True)
def _cut_at(idx, Q, vals, few, below, v, tmp, tmpq):
    """``idx`` and its points ``Q`` (values ``vals``) reordered into ``tmp`` and ``tmpq`` at v, the median, in
    the bin of values ``few`` above ``below`` values: the rows below v first (or, when none is, those at v);
    returns the size of the first part."""
    m = len(idx)
    n_left = below
    at = 0
    for u in range(len(few)):  # the bin's values below v, and at v
        if few[u] < v:
            n_left += 1
        elif few[u] == v:
            at += 1
    strict = n_left > 0
    if not strict:
        n_left = at  # v is the smallest value: the rows at v go first
    a = 0
    c = n_left
    for t in range(m):  # the side a select, not a branch (which side is a coin toss: mispredicted half the time)
        first = (vals[t] < v) | ((not strict) & (vals[t] == v))
        d = a if first else c
        tmp[d] = idx[t]
        for j in range(3):
            tmpq[d, j] = Q[t, j]
        a += first
        c += not first
    return n_left
