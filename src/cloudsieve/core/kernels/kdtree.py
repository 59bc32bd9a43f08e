"""A small k-d tree inside one cluster, for the compiled neighbour queries (checked input, see :mod:`.knn`).

Median splits of the widest side, leaves of at most ``leaf`` points, a box per node,
a quickselect, squared distances summed as cKDTree's. Gaps and distances round
alike, so pruning by gap is exact.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["kth_smallest", "nth_element", "build_tree", "box_gap2", "dist2", "gather"]


@njit(cache=True, nogil=True, inline="always")
def kth_smallest(a, n, k, s0, s1):
    """The k-th smallest (0-based) of a[:n], a unchanged; s0, s1 scratch of >= n."""
    for u in range(n):
        s0[u] = a[u]
    src = s0
    dst = s1
    m = n
    while True:
        if m <= 8:
            for u in range(1, m):
                x = src[u]
                p = u
                while p > 0 and src[p - 1] > x:
                    src[p] = src[p - 1]
                    p -= 1
                src[p] = x
            return src[k]
        x0 = src[0]
        x1 = src[m >> 1]
        x2 = src[m - 1]
        piv = max(min(x0, x1), min(max(x0, x1), x2))  # median of three
        nl = 0
        nr = 0
        for u in range(m):  # branch-free three-way split: < piv to the left, > piv to the right
            x = src[u]
            dst[nl] = x
            dst[m - 1 - nr] = x
            nl += x < piv
            nr += x > piv
        if k < nl:
            m = nl
            src, dst = dst, src
        elif k >= m - nr:
            k -= m - nr
            for u in range(nr):
                src[u] = dst[m - 1 - u]
            m = nr
        else:
            return piv


@njit(cache=True, nogil=True, _nrt=False)
def nth_element(perm, P, s, dim, a, b, kth):
    """Reorder perm[a:b] (rows s + perm) so position kth holds its sorted element along ``dim`` (nth_element)."""
    lo = a
    hi = b - 1
    while lo < hi:
        x0 = P[s + perm[lo], dim]
        x1 = P[s + perm[(lo + hi) >> 1], dim]
        x2 = P[s + perm[hi], dim]
        piv = max(min(x0, x1), min(max(x0, x1), x2))
        i = lo
        j = hi
        while i <= j:
            while P[s + perm[i], dim] < piv:
                i += 1
            while P[s + perm[j], dim] > piv:
                j -= 1
            if i <= j:
                t = perm[i]
                perm[i] = perm[j]
                perm[j] = t
                i += 1
                j -= 1
        if kth <= j:
            hi = j
        elif kth >= i:
            lo = i
        else:
            return


@njit(cache=True, nogil=True, _nrt=False)
def build_tree(P, s, m, leaf, perm, X, node, box, stack):
    """A k-d tree of the cluster P[s:s+m] (median splits, leaves <= leaf points); returns the node count.

    X (3, m): coordinates in leaf order; perm: cluster positions; node[i] = (start,
    end, left child or -1, parent); box[i] = (x0, x1, y0, y1, z0, z1). Node 0 is the root.
    """
    for t in range(m):
        perm[t] = t
    node[0, 0] = 0
    node[0, 1] = m
    node[0, 3] = -1
    nnode = 1
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        i = stack[top]
        a = node[i, 0]
        b = node[i, 1]
        x0 = y0 = z0 = np.inf
        x1 = y1 = z1 = -np.inf
        for t in range(a, b):
            q = s + perm[t]
            x0 = min(x0, P[q, 0])
            x1 = max(x1, P[q, 0])
            y0 = min(y0, P[q, 1])
            y1 = max(y1, P[q, 1])
            z0 = min(z0, P[q, 2])
            z1 = max(z1, P[q, 2])
        box[i, 0] = x0
        box[i, 1] = x1
        box[i, 2] = y0
        box[i, 3] = y1
        box[i, 4] = z0
        box[i, 5] = z1
        if b - a <= leaf:
            node[i, 2] = -1
            continue
        wx = x1 - x0
        wy = y1 - y0
        wz = z1 - z0
        dim = 0 if (wx >= wy and wx >= wz) else (1 if wy >= wz else 2)
        mid = (a + b) >> 1
        nth_element(perm, P, s, dim, a, b, mid)
        node[i, 2] = nnode  # children nnode (left) and nnode + 1
        node[nnode, 0] = a
        node[nnode, 1] = mid
        node[nnode + 1, 0] = mid
        node[nnode + 1, 1] = b
        node[nnode, 3] = node[nnode + 1, 3] = i
        stack[top] = nnode + 1
        stack[top + 1] = nnode  # left first
        nnode += 2
        top += 2
    for t in range(m):
        q = s + perm[t]
        X[0, t] = P[q, 0]
        X[1, t] = P[q, 1]
        X[2, t] = P[q, 2]
    return nnode


@njit(cache=True, nogil=True, inline="always")
def box_gap2(box, L, l2):
    """Squared gap between the boxes of nodes L and l2 (0 when they overlap)."""
    ax = max(max(box[l2, 0] - box[L, 1], box[L, 0] - box[l2, 1]), 0.0)
    ay = max(max(box[l2, 2] - box[L, 3], box[L, 2] - box[l2, 3]), 0.0)
    az = max(max(box[l2, 4] - box[L, 5], box[L, 4] - box[l2, 5]), 0.0)
    return ax * ax + ay * ay + az * az


@njit(cache=True, nogil=True, inline="always")
def dist2(C, a, b, x, y, z, out):
    """Squared distances from (x, y, z) to C[:, a:b] into out[:b - a], summed as cKDTree sums them."""
    for u in range(b - a):
        dx = C[0, a + u] - x
        dy = C[1, a + u] - y
        dz = C[2, a + u] - z
        out[u] = dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True, inline="always")
def gather(X, perm, a, b, C, cj, nC):
    for v in range(a, b):
        C[0, nC] = X[0, v]
        C[1, nC] = X[1, v]
        C[2, nC] = X[2, v]
        cj[nC] = perm[v]
        nC += 1
    return nC
