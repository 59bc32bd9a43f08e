"""Compiled kernel of the LAS records' coordinates (numba; private: inputs are assumed valid).

Written here because numpy reads a field of a structured array (a record's
stride apart) through its generic strided loop, one element at a time:
X, Y, Z copied into an (n, 3) int64 array, re-quantised, cast to int32
and decoded to float64 take twenty times or more as long as one pass over the
record bytes here. laspy keeps the records as bytes; no library reads three
fields of them into one array.

:func:`las_xyz` takes a range of rows, so the caller may run disjoint ranges
on threads (``nogil``); the result does not depend on the ranges.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["las_xyz", "first_call"]


@njit(cache=True, nogil=True)
def las_xyz(rec, offs, mult, add, scale, offset, ints, coords, s, e, lo, hi):
    """Rows s..e-1 of the records *rec* (n, size) uint8: X, Y, Z the little-endian int32 at the byte
    offsets ``offs`` (3,) int64, re-quantised ``v = X * mult + add`` (int64, (3,) each).

    Written to *ints* (n, 3) int32 when *coords* has no rows, else to *coords* (n, 3) float64 as
    ``v * scale + offset`` (the store's decoding: numpy's ``np.multiply(raw, scale) + offset``, the same
    two roundings). *lo*, *hi* (3,) int64 take the extremes of v over the rows (min / max with their
    values on entry); a v outside int32 is written truncated (the caller checks lo and hi).
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
    """:func:`las_xyz` on no rows, with the argument types of the real calls: numba's first call in a
    process (its registries: made while lazrs decodes) or the warm-up's compile."""
    i64 = np.zeros(3, dtype=np.int64)
    las_xyz(np.zeros((0, 16), dtype=np.uint8), i64, i64, i64, np.zeros(3), np.zeros(3),
            np.zeros((0, 3), dtype=np.int32), np.zeros((0, 3)), 0, 0, i64.copy(), i64.copy())
