"""Rows grouped by label and back to input order (numba; private, inputs assumed valid)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .threads import Chunks

__all__ = ["from_groups", "group_rows"]


@njit(cache=True)
def from_groups(labels, offset, src):
    """``out[i] = src[offset[labels[i]] + r]``, r the preceding rows with row i's label: inverse of a stable sort by label."""
    pos = offset.copy()
    out = np.empty(len(labels), dtype=src.dtype)
    for i in range(len(labels)):
        c = labels[i]
        out[i] = src[pos[c]]
        pos[c] += 1
    return out


@njit(cache=True, nogil=True)
def _label_counts(labels, start, stop, counts):
    """counts[c] = rows of [start, stop) with label c."""
    for i in range(start, stop):
        counts[labels[i]] += 1


@njit(cache=True, nogil=True)
def _place_rows(labels, start, stop, pos, out):
    """Each row i of [start, stop), ascending, to ``out[pos[labels[i]]]``, that position then moved on."""
    for i in range(start, stop):
        c = labels[i]
        out[pos[c]] = i
        pos[c] += 1


#: rows a thread of :func:`group_rows` takes at least (below, a thread's start costs more than its share)
GROUP_ROWS = 1_000_000


def group_rows(labels, n_labels: int, threads: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``np.argsort(labels, kind="stable")`` of labels in [0, n_labels), and each label's bounds (n_labels + 1,).

    By counting, over *threads* row ranges; the same array on any thread count.
    """
    n = len(labels)
    if n_labels == 1:  # one cell (every small input): the rows as they are, no kernel to load
        return np.arange(n, dtype=np.int64), np.array([0, n], dtype=np.int64)
    parts = max(1, min(int(threads), n // GROUP_ROWS + 1))
    cuts = np.linspace(0, n, parts + 1).astype(np.int64)
    counts = np.zeros((parts, n_labels), dtype=np.int64)
    with Chunks(parts) as chunks:
        chunks.each(lambda t: _label_counts(labels, cuts[t], cuts[t + 1], counts[t]), range(parts))
        bounds = np.zeros(n_labels + 1, dtype=np.int64)
        np.cumsum(counts.sum(axis=0), out=bounds[1:])
        pos = bounds[:-1] + np.cumsum(counts, axis=0) - counts  # where each range's rows of each label start
        out = np.empty(n, dtype=np.int64)
        chunks.each(lambda t: _place_rows(labels, cuts[t], cuts[t + 1], pos[t], out), range(parts))
    return out, bounds
