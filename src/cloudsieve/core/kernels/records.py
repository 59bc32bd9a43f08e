"""Compiled kernel of the LAS records' coordinates (numba; private: inputs are assumed valid).

numpy reads a structured field element by element; one pass over the record bytes
is far faster. :func:`las_xyz` takes a row range for threads (``nogil``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["las_xyz", "first_call"]


@njit(cache=True, nogil=True)
def las_xyz(rec, offs, mult, add, scale, offset, ints, coords, s, e, lo, hi):
    """Rows s..e-1 of records *rec* (n, size) uint8: little-endian int32 X, Y, Z at ``offs`` (3,), re-quantised ``v = X * mult + add``.

    Written to *ints* (n, 3) int32 when *coords* has no rows, else to *coords* (n, 3)
    float64 as ``v * scale + offset`` (numpy's two roundings). *lo*, *hi* (3,) int64
    accumulate v's extremes; v outside int32 is truncated (the caller checks lo, hi).
    """
    decode = coords.shape[0] > 0
    for i in range(s, e):
        for j in range(3):
            o = offs[j]
            u = (np.uint32(rec[i, o]) | (np.uint32(rec[i, o + 1]) << np.uint32(8))
                 | (np.uint32(rec[i, o + 2]) << np.uint32(16)) | (np.uint32(rec[i, o + 3]) << np.uint32(24)))
            v = np.int64(np.int32(u)) * mult[j] + add[j]
            if v < lo[j]:
                lo[j] = v
            if v > hi[j]:
                hi[j] = v
            if decode:
                coords[i, j] = np.float64(v) * scale[j] + offset[j]
            else:
                ints[i, j] = np.int32(v)


def first_call() -> None:
    """:func:`las_xyz` on no rows with the real argument types: numba's first call or the warm-up's compile."""
    i64 = np.zeros(3, dtype=np.int64)
    las_xyz(np.zeros((0, 16), dtype=np.uint8), i64, i64, i64, np.zeros(3), np.zeros(3),
            np.zeros((0, 3), dtype=np.int32), np.zeros((0, 3)), 0, 0, i64.copy(), i64.copy())
