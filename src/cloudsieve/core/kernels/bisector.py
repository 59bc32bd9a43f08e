"""Compiled kernel of the eliminate rule's bands: distances to bisector planes (numba; private).

One pass over the points for all planes; the arithmetic is
:func:`cloudsieve.engine.halo.halo_distance`'s, in its order, so masks match point for point.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def within_any(z, mid, diff, norm, margin):
    """Which rows of z (n, 3) have ((z - mid[q]) . diff[q]) / norm[q] <= margin for some plane q."""
    n = len(z)
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        for q in range(len(norm)):
            d = (z[i, 0] - mid[q, 0]) * diff[q, 0] + (z[i, 1] - mid[q, 1]) * diff[q, 1]
            d = d + (z[i, 2] - mid[q, 2]) * diff[q, 2]
            if d / norm[q] <= margin:
                out[i] = True
                break
    return out
