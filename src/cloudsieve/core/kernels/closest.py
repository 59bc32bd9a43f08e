"""The k nearest of a few sites (cell centres) for many points, compiled with numba.

For the partition's label pass (2 nearest centres per point, 6 near a border),
where cKDTree's answer is mostly per-query overhead: a k-d tree of the sites
(:func:`.kdtree.build_tree`, leaves of at most ``LEAF``), walked nearer child
first, pruned by box gaps. Exact, cKDTree's distances bit for bit (same summation,
monotone gaps, pruning only on a strictly larger gap); rows ordered by (squared
distance, site index).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kdtree import build_tree

__all__ = ["LEAF", "site_tree", "nearest_sites"]

LEAF = 8


@njit(cache=True, nogil=True, inline="always")
def _gap2(box, i, x, y, z):
    """Squared gap from (x, y, z) to the box of node i (0 inside)."""
    gx = max(max(box[i, 0] - x, x - box[i, 1]), 0.0)
    gy = max(max(box[i, 2] - y, y - box[i, 3]), 0.0)
    gz = max(max(box[i, 4] - z, z - box[i, 5]), 0.0)
    return gx * gx + gy * gy + gz * gz


@njit(cache=True, nogil=True, _nrt=False)
def _query(P, k, S, perm, node, box, stack, gaps, out_d, out_i):
    """The k nearest sites of every row of P (k <= sites) into out_d (distances) and out_i (site indices)."""
    for q in range(len(P)):
        x = P[q, 0]
        y = P[q, 1]
        z = P[q, 2]
        for u in range(k):
            out_d[q, u] = np.inf
            out_i[q, u] = -1
        stack[0] = 0
        gaps[0] = _gap2(box, 0, x, y, z)
        top = 1
        while top > 0:
            top -= 1
            i = stack[top]
            if gaps[top] > out_d[q, k - 1]:  # squared until the end; strict: a tie may have a lower index
                continue
            c = node[i, 2]
            if c >= 0:
                g0 = _gap2(box, c, x, y, z)
                g1 = _gap2(box, c + 1, x, y, z)
                near, far, gn, gf = (c, c + 1, g0, g1) if g0 <= g1 else (c + 1, c, g1, g0)
                stack[top] = far
                gaps[top] = gf
                stack[top + 1] = near
                gaps[top + 1] = gn
                top += 2
                continue
            for t in range(node[i, 0], node[i, 1]):
                dx = S[0, t] - x
                dy = S[1, t] - y
                dz = S[2, t] - z
                d2 = dx * dx + dy * dy + dz * dz
                j = perm[t]
                if d2 > out_d[q, k - 1] or (d2 == out_d[q, k - 1] and j > out_i[q, k - 1] >= 0):
                    continue
                u = k - 1
                while u > 0 and (d2 < out_d[q, u - 1] or (d2 == out_d[q, u - 1] and j < out_i[q, u - 1])):
                    out_d[q, u] = out_d[q, u - 1]
                    out_i[q, u] = out_i[q, u - 1]
                    u -= 1
                out_d[q, u] = d2
                out_i[q, u] = j
        for u in range(k):
            out_d[q, u] = np.sqrt(out_d[q, u])


def site_tree(sites: np.ndarray) -> tuple:
    """The k-d tree of *sites* (m, 3) float64, m >= 1, for :func:`nearest_sites`."""
    C = np.ascontiguousarray(sites, dtype=np.float64)
    m = len(C)
    cap = 2 * m + 1
    perm = np.empty(m, dtype=np.int64)
    S = np.empty((3, m))
    node = np.empty((cap, 4), dtype=np.int64)
    box = np.empty((cap, 6))
    stack = np.empty(cap, dtype=np.int64)
    nnode = build_tree(C, np.int64(0), m, LEAF, perm, S, node, box, stack)
    return S, perm, node[:nnode].copy(), box[:nnode].copy()


def nearest_sites(tree: tuple, points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances (n, k) float64 and indices (n, k) int64 of the k nearest sites of each point.

    *tree* from :func:`site_tree`; 1 <= k <= sites; *points* (n, 3) float64, finite.
    """
    S, perm, node, box = tree
    P = np.ascontiguousarray(points, dtype=np.float64)
    out_d = np.empty((len(P), k))
    out_i = np.empty((len(P), k), dtype=np.int64)
    depth = 2 * len(node) + 2  # the stack holds at most one pending sibling per level, plus the two children
    _query(P, int(k), S, perm, node, box, np.empty(depth, dtype=np.int64), np.empty(depth), out_d, out_i)
    return out_d, out_i
