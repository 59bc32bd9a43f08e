"""Compiled kernel of exact copies: the first row equal to each row, by hashing (numba; private).

One pass over an open-addressing table, where sorting rows costs a sort of the
many ties of quantised LAS data.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def first_equal(B):
    """Index of the first row equal to each row of ``B`` (n, p) uint64: float64 bits with -0.0 made +0.0."""
    n, p = B.shape
    size = 1
    while size < 2 * n:
        size *= 2
    mask = np.uint64(size - 1)
    table = np.full(size, -1, dtype=np.int64)
    first = np.empty(n, dtype=np.int64)
    for i in range(n):
        h = np.uint64(0x9E3779B97F4A7C15)
        for j in range(p):  # splitmix64-style mixing of each word
            h = (h ^ B[i, j]) * np.uint64(0xBF58476D1CE4E5B9)
            h ^= h >> np.uint64(31)
        s = (h * np.uint64(0x94D049BB133111EB)) >> np.uint64(17)
        while True:
            e = table[np.int64(s & mask)]
            if e < 0:
                table[np.int64(s & mask)] = i
                first[i] = i
                break
            same = True
            for j in range(p):
                if B[e, j] != B[i, j]:
                    same = False
                    break
            if same:
                first[i] = e
                break
            s += np.uint64(1)
    return first
