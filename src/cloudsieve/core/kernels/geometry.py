"""Compiled kernels of local geometry (numba; private, inputs assumed valid).

Same grid arguments as :mod:`.eliminate` (points in internal order, ``cell``,
``cstart``, ``nstart``/``ncells``, ``state``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, _nrt=False)
def _smallest_share(a00, a01, a02, a11, a12, a22):
    """lambda_min / (l0 + l1 + l2) of a symmetric positive semi-definite 3 x 3 matrix (closed form)."""
    tr = a00 + a11 + a22
    if tr <= 0.0:
        return 0.0
    q = tr / 3.0
    b00 = a00 - q
    b11 = a11 - q
    b22 = a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)
    if p2 <= 0.0:
        return 1.0 / 3.0
    p = math.sqrt(p2 / 6.0)
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    r = min(1.0, max(-1.0, det / (2.0 * p * p * p)))
    lmin = q + 2.0 * p * math.cos(math.acos(r) / 3.0 + 2.0 * math.pi / 3.0)
    return max(0.0, lmin) / tr


@njit(cache=True, parallel=True)
def surface_variation(P, cell, cstart, nstart, ncells, state, radius, min_count):
    """sigma (n,) = l0 / (l0 + l1 + l2) of the covariance of the alive points within ``radius`` of each
    alive point, itself included (Pauly et al. 2002); 0.0 with fewer than ``min_count`` of them."""
    n = len(P)
    out = np.zeros(n)
    rr = radius * radius
    for i in prange(n):
        if state[i] == 0:
            continue
        c = cell[i]
        cnt = 0
        s = np.zeros(9)  # sums of dx, dy, dz, dx dx, dx dy, dx dz, dy dy, dy dz, dz dz
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            for j in range(cstart[cc], cstart[cc + 1]):
                if state[j] == 0:
                    continue
                dx = P[j, 0] - P[i, 0]
                dy = P[j, 1] - P[i, 1]
                dz = P[j, 2] - P[i, 2]
                if dx * dx + dy * dy + dz * dz <= rr:
                    cnt += 1
                    s[0] += dx
                    s[1] += dy
                    s[2] += dz
                    s[3] += dx * dx
                    s[4] += dx * dy
                    s[5] += dx * dz
                    s[6] += dy * dy
                    s[7] += dy * dz
                    s[8] += dz * dz
        if cnt >= min_count:
            mx, my, mz = s[0] / cnt, s[1] / cnt, s[2] / cnt
            out[i] = _smallest_share(s[3] / cnt - mx * mx, s[4] / cnt - mx * my, s[5] / cnt - mx * mz,
                                     s[6] / cnt - my * my, s[7] / cnt - my * mz, s[8] / cnt - mz * mz)
    return out
