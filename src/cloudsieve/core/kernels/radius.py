"""The other points within a radius inside clusters, compiled with numba.

:func:`within_radius` returns, for every point, the other points of its own
cluster at squared distance <= r*r (the squared distance summed as cKDTree
sums it, so the same points as ``cKDTree.query_ball_point(x, r)``), as a CSR
graph ordered by (distance, row) in each row. The clusters get the k-d tree
of :mod:`.kdtree` (leaves of 16 points); the candidates of a leaf are the
leaves whose box lies within r of its box. Two passes: counts, then the rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...errors import InvalidParameterError
from .kdtree import box_gap2, build_tree, dist2, gather
from .knn import check_grouped, run_chunks

__all__ = ["within_radius"]

LEAF = 16


@njit(cache=True, nogil=True)
def _cluster(P, s, m, r2, query, counts, rowptr, out_i, out_d, fill, w):
    perm, X, node, box, stack, C, cj, tmp, cd, ci, s0, si, rank = w
    for r in range(s, s + m):
        counts[r] = 0
    if m <= 1:
        return
    nnode = build_tree(P, s, m, LEAF, perm, X, node, box, stack)
    for L in range(nnode):
        if node[L, 2] >= 0:
            continue
        a0 = node[L, 0]
        a1 = node[L, 1]
        todo = False
        for t in range(a0, a1):
            todo |= query[s + perm[t]]
        if not todo:
            continue
        nC = gather(X, perm, a0, a1, C, cj, 0)  # L's points first, then every leaf within r of L's box
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            i = stack[top]
            if i == L or box_gap2(box, L, i) > r2:
                continue
            if node[i, 2] < 0:
                nC = gather(X, perm, node[i, 0], node[i, 1], C, cj, nC)
            else:
                stack[top] = node[i, 2]
                stack[top + 1] = node[i, 2] + 1
                top += 2
        for t in range(a0, a1):
            row = s + perm[t]
            if not query[row]:
                continue
            dist2(C, 0, nC, X[0, t], X[1, t], X[2, t], tmp)
            tmp[t - a0] = np.inf  # the point itself
            nc = 0
            for u in range(nC):
                x = tmp[u]
                cd[nc] = x
                ci[nc] = cj[u]
                nc += x <= r2
            counts[row] = nc
            if not fill:
                continue
            for u in range(nc):  # rank by (squared distance, row)
                x = cd[u]
                j = ci[u]
                rk = 0
                for v in range(nc):
                    rk += (cd[v] < x) | ((cd[v] == x) & (ci[v] < j))
                rank[u] = rk
            for u in range(nc):
                s0[rank[u]] = cd[u]
                si[rank[u]] = ci[u]
            o = rowptr[row]
            for u in range(nc):
                out_d[o + u] = np.sqrt(s0[u])
                out_i[o + u] = s + si[u]


@njit(cache=True, nogil=True)
def _chunk(P, indptr, r2c, c0, c1, query, counts, rowptr, out_i, out_d, fill):
    mmax = 1
    for c in range(c0, c1):
        mmax = max(mmax, indptr[c + 1] - indptr[c])
    w = (
        np.empty(mmax, np.int64),  # perm
        np.empty((3, mmax)),  # X
        np.empty((2 * mmax + 1, 4), np.int64),  # node
        np.empty((2 * mmax + 1, 6)),  # box
        np.empty(256, np.int64),  # stack
        np.empty((3, mmax)),  # C
        np.empty(mmax, np.int64),  # cj
        np.empty(mmax),  # tmp
        np.empty(mmax),  # cd
        np.empty(mmax, np.int64),  # ci
        np.empty(mmax),  # s0
        np.empty(mmax, np.int64),  # si
        np.empty(mmax, np.int64),  # rank
    )
    for c in range(c0, c1):
        s = indptr[c]
        _cluster(P, s, indptr[c + 1] - s, r2c[c], query, counts, rowptr, out_i, out_d, fill, w)


def within_radius(points, indptr, radius, *, query=None, threads: int | None = None):
    """The other points within ``radius`` of every point, inside its own cluster.

    Parameters
    ----------
    points : array_like of shape (n, p), float, 1 <= p <= 3
        Finite coordinates grouped by cluster: cluster j is
        ``points[indptr[j]:indptr[j + 1]]``.
    indptr : array_like of shape (c + 1,), int
        Cluster starts, from 0 to n, non-decreasing.
    radius : float or array_like of shape (c,), float >= 0
        One radius, or one per cluster.
    query : array_like of shape (n,), bool, optional
        Only these rows are answered (the others get no neighbours).
    threads : int, optional
        Threads (default: all cores); the result does not depend on it.

    Returns
    -------
    rowptr : ndarray of shape (n + 1,), int64
    indices : ndarray of shape (nnz,), int64
        Row i's neighbours are ``indices[rowptr[i]:rowptr[i + 1]]``, nearest
        first (ties: lower row first), the point itself excluded.
    distances : ndarray of shape (nnz,), float64
        Their distances, bit for bit those of cKDTree.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0], [10, 0, 0], [12, 0, 0.]])
    >>> ptr, idx, d = within_radius(pts, [0, 3, 5], 2.0)
    >>> ptr.tolist(), idx.tolist(), d.tolist()
    ([0, 1, 3, 4, 5, 6], [1, 0, 2, 1, 4, 3], [1.0, 1.0, 2.0, 2.0, 2.0, 2.0])
    """
    P, ip, q = check_grouped(points, indptr, query)
    c = len(ip) - 1
    r = np.asarray(radius, dtype=np.float64)
    if r.ndim > 1 or (r.ndim == 1 and len(r) != c):
        raise InvalidParameterError(f"radius must be a number or {c} numbers (one per cluster), got shape {r.shape}")
    r = np.broadcast_to(r, (c,))
    if c and not (np.isfinite(r) & (r >= 0)).all():
        j = int(np.flatnonzero(~(np.isfinite(r) & (r >= 0)))[0])
        raise InvalidParameterError(f"radius must be finite and >= 0, got {float(r[j])!r} for cluster {j}")
    r2 = np.ascontiguousarray(r * r)
    n = len(P)
    counts = np.zeros(n, dtype=np.int64)
    rowptr = np.zeros(n + 1, dtype=np.int64)
    if c == 0 or n == 0:
        return rowptr, np.zeros(0, dtype=np.int64), np.zeros(0)
    run_chunks(_chunk, ip, threads, P, ip, r2, q, counts, rowptr, np.zeros(0, np.int64), np.zeros(0), False)
    np.cumsum(counts, out=rowptr[1:])
    out_i = np.empty(int(rowptr[-1]), dtype=np.int64)
    out_d = np.empty(int(rowptr[-1]))
    run_chunks(_chunk, ip, threads, P, ip, r2, q, counts, rowptr, out_i, out_d, True)
    return rowptr, out_i, out_d
