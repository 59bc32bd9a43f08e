"""Compiled kernels of the in-memory cells of ``eliminate`` (numba; private, inputs assumed valid).

numpy takes a fancy-indexed copy of the rows and two boolean masks per
split: the split of 1 M points into 64 cells took 0.13 s in numpy; here the
coordinate is gathered once and the rows split in one pass (numpy's
partition finds the median: twice as fast as numba's).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def gather(P, idx, axis, vals):
    """vals[t] = P[idx[t], axis]."""
    for t in range(len(idx)):
        vals[t] = P[idx[t], axis]


@njit(cache=True, nogil=True)
def split_at(idx, vals, v, tmp):
    """Reorder ``idx`` (values ``vals``) in place: the rows below v first, then the others, each in their
    order; when none is below v, those at v first. Returns the position of the first of the second part
    (0 or len(idx) when there is no split)."""
    m = len(idx)
    strict = False
    for t in range(m):
        if vals[t] < v:
            strict = True
            break
    k = 0
    for t in range(m):  # first part: below v (at most v when none is below)
        if vals[t] < v or (not strict and vals[t] == v):
            tmp[k] = idx[t]
            k += 1
    mid = k
    for t in range(m):
        if not (vals[t] < v or (not strict and vals[t] == v)):
            tmp[k] = idx[t]
            k += 1
    idx[:] = tmp[:m]
    return mid


@njit(cache=True, nogil=True)
def band_flags(P, idx, starts, boxes, margin):
    """For every point: whether it lies within ``margin`` of a face of its cell's box (``boxes`` (C, 2, 3),
    the points of cell c are ``idx[starts[c]:starts[c + 1]]``), i.e. may be in a neighbour's halo."""
    out = np.zeros(len(P), dtype=np.bool_)
    for c in range(len(starts) - 1):
        for t in range(starts[c], starts[c + 1]):
            i = idx[t]
            for j in range(3):
                if P[i, j] < boxes[c, 0, j] + margin or P[i, j] > boxes[c, 1, j] - margin:
                    out[i] = True
                    break
    return out
