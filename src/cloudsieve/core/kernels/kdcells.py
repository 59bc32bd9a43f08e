"""Compiled kernels of the in-memory cells of ``eliminate`` (numba; private, inputs assumed valid).

:func:`median_cut` moves points with their rows, so cells come out as contiguous blocks.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def band_rows(Q, box, margin):
    """Positions of the points ``Q`` of one cell within ``margin`` of a face of its box (2, 3), in order."""
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
    """Rows of the bands of ``cells`` (cell c's: ``band[bstart[c]:bstart[c + 1]]``) inside the closed box [lo, hi], in order."""
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
    """Cut rows ``idx`` with their points ``Q`` at the median v of coordinate ``axis`` (values in [lo, hi]).

    Rows below v first (none below: those at v first), each part in order, written to
    ``tmp`` and ``tmpq``; ``idx`` and ``Q`` are unchanged. v is the exact (m // 2)-th
    smallest value, found by a histogram over ``len(counts)`` bins, then a partition of
    the median's bin. ``vals``: scratch of >= len(idx). Returns (v, start of the second
    part: 0 or len(idx) when no cut exists).
    """
    few, below = _median_bin(Q, axis, lo, hi, vals, counts)
    v = float(np.partition(few, len(idx) // 2 - below)[len(idx) // 2 - below])
    return v, _cut_at(idx, Q, vals, few, below, v, tmp, tmpq)


@njit(cache=True, nogil=True)
def _median_bin(Q, axis, lo, hi, vals, counts):
    """Values of coordinate ``axis`` into ``vals``; those of the bin holding rank len(Q) // 2, and the count below it."""
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
    """Reorder ``idx``, ``Q`` into ``tmp``, ``tmpq`` at the median v (in bin values ``few``, above ``below`` values); returns the first part's size."""
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
