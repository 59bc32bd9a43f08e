"""Exact k nearest neighbours inside clusters, compiled with numba.

:func:`knn_unchecked`: for every point, its k nearest *other* points of its own
cluster (cluster j is ``points[indptr[j]:indptr[j + 1]]``), the distances bit for
bit those of ``cKDTree(cluster).query(cluster, k + 1)`` minus the first column:
squared distances are summed as cKDTree does, ``(dx*dx + dy*dy) + dz*dz``, without
FMA; zero padding adds exactly 0.0. Ties: the k smallest (squared distance, row)
pairs, so rows may differ from cKDTree's only among equal distances.

Per cluster a k-d tree (median splits, boxes per node); per leaf, a bound T0 from
the smallest node with more than k points picks the candidate leaves; candidates
within T0 are kept branch-free, trimmed by quickselect, ordered by rank. Clusters
run on threads (nogil).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kdtree import box_gap2, build_tree, dist2, gather, kth_smallest
from .threads import run_chunks

__all__ = ["knn_unchecked", "knn_scored", "take_neighbours"]

# leaves hold at most max(LEAF_MIN, k + LEAF_EXTRA) points; the first bound comes from a node of
# more than BOUND_NODE * k points; candidates are trimmed to the k nearest above k + TRIM (values not critical)
LEAF_MIN = 16
LEAF_EXTRA = 0
BOUND_NODE = 2
TRIM = 8


@njit(cache=True, nogil=True, _nrt=False)
def _cluster(P, s, m, kq, K, query, leaf, bound_node, trim, out_d, out_i, w):
    """The kq nearest of each point of the cluster P[s:s+m] into out rows s..s+m-1."""
    perm, X, node, box, stack, C, cj, tmp, cd, ci, s0, s1, si, t0, rank = w
    kk = min(kq, m - 1)
    for r in range(s, s + m):
        for u in range(0 if not query[r] else max(kk, 0), K):
            out_d[r, u] = np.inf
            out_i[r, u] = -1
    if kk <= 0:
        return
    nnode = build_tree(P, s, m, leaf, perm, X, node, box, stack)
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
        # first bound T0 of each point: its kk-th nearest in the smallest node around L with > kk points
        up = L
        while node[up, 1] - node[up, 0] <= bound_node * kk and up > 0:
            up = node[up, 3]
        p0 = node[up, 0]
        n1 = node[up, 1] - p0
        R = -1.0
        for t in range(a0, a1):
            if query[s + perm[t]]:
                dist2(X, p0, p0 + n1, X[0, t], X[1, t], X[2, t], tmp)
                tmp[t - p0] = np.inf  # the point itself
                t0[t - a0] = kth_smallest(tmp, n1, kk - 1, s0, s1)
                R = max(R, t0[t - a0])
        # candidates: L's points first (in order), then every leaf whose box is within R of L's
        nC = gather(X, perm, a0, a1, C, cj, 0)
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            i = stack[top]
            if i == L or box_gap2(box, L, i) > R:
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
            T = t0[t - a0]
            dist2(C, 0, nC, X[0, t], X[1, t], X[2, t], tmp)
            tmp[t - a0] = np.inf
            nc = 0
            for u in range(nC):  # keep the candidates within T (branch-free)
                x = tmp[u]
                cd[nc] = x
                ci[nc] = cj[u]
                nc += x <= T
            if nc > kk + trim:
                T = kth_smallest(cd, nc, kk - 1, s0, s1)
                n2 = 0
                for u in range(nc):
                    x = cd[u]
                    cd[n2] = x
                    ci[n2] = ci[u]
                    n2 += x <= T
                nc = n2
            for u in range(nc):  # rank by (squared distance, row): the sorted position
                x = cd[u]
                j = ci[u]
                rk = 0
                for v in range(nc):
                    rk += (cd[v] < x) | ((cd[v] == x) & (ci[v] < j))
                rank[u] = rk
            for u in range(nc):
                s0[rank[u]] = cd[u]
                si[rank[u]] = ci[u]
            for u in range(kk):
                out_d[row, u] = np.sqrt(s0[u])
                out_i[row, u] = s + si[u]


@njit(cache=True, nogil=True)
def _scratch(mmax, lmax):
    """Scratch arrays of :func:`_cluster` for clusters of <= mmax points and leaves of <= lmax points."""
    return (
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
        np.empty(mmax),  # s1
        np.empty(mmax, np.int64),  # si
        np.empty(lmax),  # t0
        np.empty(mmax, np.int64),  # rank
    )


@njit(cache=True, nogil=True)
def _chunk(P, indptr, kc, c0, c1, K, query, leaf_min, leaf_extra, bound_node, trim, out_d, out_i):
    """Clusters c0..c1-1, with scratch arrays allocated once."""
    mmax = np.int64(1)  # not the literal 1: one signature of _scratch
    kmax = 1
    for c in range(c0, c1):
        mmax = max(mmax, indptr[c + 1] - indptr[c])
        kmax = max(kmax, kc[c])
    lmax = max(leaf_min, kmax + leaf_extra)
    w = _scratch(mmax, lmax)
    for c in range(c0, c1):
        s = indptr[c]
        leaf = max(leaf_min, kc[c] + leaf_extra)
        _cluster(P, s, indptr[c + 1] - s, kc[c], K, query, leaf, bound_node, trim, out_d, out_i, w)


@njit(cache=True, nogil=True)
def _score_chunk(pts, order, indptr, c0, c1, kcl, koff, leaf_min, leaf_extra, bound_node, trim, rk, rk1, nb, flag):
    """Clusters c0..c1-1 with kcl > 0, their points pts[order[indptr[c]:indptr[c + 1]]]: r_k, r_(k+1)
    and the k nearest (grouped positions) of each point, or flag[c] when a point has a copy."""
    mmax = np.int64(1)  # not the literal 1: one signature of _scratch
    kmax = 1
    for c in range(c0, c1):
        if kcl[c] > 0:
            mmax = max(mmax, indptr[c + 1] - indptr[c])
            kmax = max(kmax, kcl[c])
    lmax = max(leaf_min, kmax + 1 + leaf_extra)
    w = _scratch(mmax, lmax)
    Pc = np.zeros((mmax, 3))  # zero columns for 1- and 2-D points
    q = np.ones(mmax, np.bool_)
    od = np.empty((mmax, kmax + 1))
    oi = np.empty((mmax, kmax + 1), np.int64)
    p = min(pts.shape[1], 3)
    for c in range(c0, c1):
        k = kcl[c]
        if k <= 0:
            continue
        s = indptr[c]
        m = indptr[c + 1] - s
        for t in range(m):
            i = order[s + t]
            for d in range(p):
                Pc[t, d] = pts[i, d]
        leaf = max(leaf_min, k + 1 + leaf_extra)
        _cluster(Pc, np.int64(0), m, k + 1, k + 1, q, leaf, bound_node, trim, od, oi, w)
        z = False
        for t in range(m):
            z |= od[t, 0] == 0.0
        if z:
            flag[c] = True
            continue
        o = koff[c]
        for t in range(m):
            rk[s + t] = od[t, k - 1]
            rk1[s + t] = od[t, k]
            for j in range(k):
                nb[o + j] = s + oi[t, j]
            o += k


def knn_unchecked(P, indptr, kc, query, threads=None):
    """The kc[j] nearest other points of every point of cluster j, inside its cluster (checked input).

    P (n, 3) float64 C-contiguous, grouped by cluster (1- and 2-D points zero-padded);
    indptr (c + 1,) int64; kc (c,) int64 >= 0; query (n,) bool: rows answered (others
    padded). The result does not depend on ``threads`` (default: all cores).

    Returns distances (n, K) float64, K = max(kc), ascending, +inf after the cluster's
    k (or m - 1) columns; indices (n, K) int64 (ties: lower row first), -1 at +inf.

    >>> import numpy as np
    >>> pts = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0], [10, 0, 0], [12, 0, 0.]])
    >>> d, i = knn_unchecked(pts, np.array([0, 3, 5]), np.array([2, 2]), np.ones(5, bool), 1)
    >>> d.tolist(), i.tolist()
    ([[1.0, 3.0], [1.0, 2.0], [2.0, 3.0], [2.0, inf], [2.0, inf]], [[1, 2], [0, 2], [1, 0], [4, -1], [3, -1]])
    """
    n = len(P)
    K = int(kc.max(initial=0))
    out_d = np.empty((n, K))
    out_i = np.empty((n, K), dtype=np.int64)
    if K and len(indptr) > 1:
        run_chunks(_chunk, indptr, threads, P, indptr, kc, K, query, LEAF_MIN, LEAF_EXTRA, BOUND_NODE, TRIM, out_d, out_i)
    return out_d, out_i


def knn_scored(pts, order, indptr, kcl, koff, threads=None):
    """The k + 1 nearest inside each cluster, in the layout of :mod:`cloudsieve.core.scored_knn` (checked input).

    ``pts`` (n, p), 1 <= p <= 3, in input order; clusters with kcl 0 are skipped, others
    hold >= k + 2 points. Returns rk, rk1 (n,) (1.0 where not computed), nb (koff[-1],)
    as :func:`knn_unchecked` orders them, and flag (c,) bool: clusters left out because
    a point has an exact copy.
    """
    n = len(order)
    rk = np.ones(n)
    rk1 = np.ones(n)
    nb = np.empty(int(koff[-1]), dtype=np.int64)
    flag = np.zeros(len(kcl), dtype=bool)
    if n and len(kcl):
        run_chunks(_score_chunk, indptr, threads, pts, order, indptr, kcl, koff, LEAF_MIN, LEAF_EXTRA, BOUND_NODE,
                   TRIM, rk, rk1, nb, flag)
    return rk, rk1, nb, flag


@njit(cache=True, nogil=True)
def _take(idx, sel, width, rows, out):
    ident = len(rows) == 0
    for a in range(len(sel)):
        r = sel[a]
        for j in range(width):
            out[a, j] = idx[r, j] if ident else rows[idx[r, j]]


def take_neighbours(idx, sel, width, rows=None):
    """``rows[idx[sel, :width]]`` (``idx[sel, :width]`` when rows is None) in one pass; (M, width) int64.

    ``idx`` (n, K) from :func:`knn_unchecked`; ``sel`` (M,) rows of idx; ``rows`` maps
    idx's rows to other positions.
    """
    out = np.empty((len(sel), int(width)), dtype=np.int64)
    r = np.zeros(0, dtype=np.int64) if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
    _take(idx, np.ascontiguousarray(sel, dtype=np.int64), int(width), r, out)
    return out
