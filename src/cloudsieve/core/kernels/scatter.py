"""Rows in input order from rows grouped by label (numba; private, inputs assumed valid)."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["from_groups"]


@njit(cache=True)
def from_groups(labels, offset, src):
    """``out[i] = src[offset[labels[i]] + r]``, r the number of earlier rows with the label of row i.

    ``src`` holds the rows grouped by label, each group in input order,
    group ``c`` from ``offset[c]``: the inverse of a stable sort by label,
    in one pass (no sort).
    """
    pos = offset.copy()
    out = np.empty(len(labels), dtype=src.dtype)
    for i in range(len(labels)):
        c = labels[i]
        out[i] = src[pos[c]]
        pos[c] += 1
    return out
