"""Point orders and the k nearest neighbours inside clusters (DESIGN.md stage 4).

:func:`canonical_order` (lexicographic), :func:`group` (by cluster, Z-order inside),
:func:`mark_duplicates`, :func:`knn_clusters` / :func:`knn_query` (k nearest *other*
points inside the own cluster, :mod:`.kernels.knn`), :func:`knn_context` (among all
points and a context, scipy's cKDTree). Input is assumed valid (:mod:`._validation`).
"""

from __future__ import annotations

import numpy as np

from ._validation import neighbour_count
from .kernels.knn import knn_unchecked, take_neighbours
from .kernels.order import grouped_order, stable_argsort

__all__ = [
    "scorable_rows",
    "canonical_order",
    "group",
    "mark_duplicates",
    "with_cluster_coordinate",
    "knn_query",
    "knn_clusters",
    "knn_context",
]


def canonical_order(X: np.ndarray) -> np.ndarray:
    """Lexicographic order of the rows of X (n, p), ties in input order; int64 (n,).

    ``np.lexsort(X.T[::-1])``, computed as a stable sort on the first column
    (:func:`.kernels.order.stable_argsort`) and a lexsort of its ties only.
    """
    X = np.asarray(X)
    if X.ndim != 2 or len(X) < 2 or X.shape[1] < 2:
        return np.lexsort(X.T[::-1]) if X.ndim == 2 and X.shape[1] else np.arange(len(X))
    x = X[:, 0]
    if x.dtype == np.float64 and not np.isnan(x).any():
        o = stable_argsort(x)  # compiled radix sort, ~3x faster than numpy's stable sort on 1 M
    else:
        o = np.argsort(x, kind="stable")
    x = x[o]
    tie = x[1:] == x[:-1]
    if tie.any():
        t = np.zeros(len(x), dtype=bool)
        t[1:] |= tie
        t[:-1] |= tie
        pos = np.flatnonzero(t)  # runs of equal x, each contiguous in o
        sub = o[pos]  # in input order within each run (stable sort)
        Y = X[sub]
        o[pos] = sub[np.lexsort(Y.T[::-1])]
    return o


def _unique_first(q: np.ndarray) -> np.ndarray:
    """Positions of the first occurrence of each distinct row of q, ascending."""
    order = np.lexsort(q.T[::-1])
    s = q[order]
    new = np.ones(len(q), dtype=bool)
    new[1:] = (s[1:] != s[:-1]).any(axis=1)
    grp = np.cumsum(new) - 1
    first = np.full(int(grp[-1]) + 1 if len(q) else 0, len(q), dtype=np.int64)
    np.minimum.at(first, grp, order)
    return np.sort(first)


def _dense_labels(lab: np.ndarray):
    """Cluster ids 0..c-1 in the order of the label values, and c (bincount when labels are small, else np.unique)."""
    n = len(lab)
    if n == 0:
        return lab.astype(np.int64), 0
    if lab.min() >= 0 and lab.max() < 2 * n + 1024:
        remap = np.cumsum(np.bincount(lab) > 0) - 1
        return remap[lab], int(remap[-1]) + 1
    u, inv = np.unique(lab, return_inverse=True)
    return inv.reshape(-1).astype(np.int64), len(u)


def group(pts: np.ndarray, labels: np.ndarray):
    """Cluster ids 0..c-1, the order grouping the clusters, and the cluster sizes.

    Returns inv (n,) int64 (cluster of each input point), order (n,) int64 (input
    indices grouped) and sizes (c,) int64. Inside a cluster rows follow a Z-order curve
    for memory locality (:func:`.kernels.order.grouped_order`).
    """
    inv, c = _dense_labels(labels)
    bits = min(21, (63 - max(1, (c - 1).bit_length())) // 3)
    order, indptr = grouped_order(pts, inv, c, bits)
    return inv, order, np.diff(indptr)


def mark_duplicates(g, ginv, rows, dup):
    """Mark in ``dup`` (n,) every copy of a preceding row of the same cluster among g[rows]; return the other rows.

    ``g`` (n, p) grouped by cluster with ids ``ginv``; ``rows`` ascending positions in g.
    """
    first = _unique_first(np.column_stack([ginv[rows].astype(np.float64), g[rows]]))
    dup[rows] = True
    distinct = rows[first]
    dup[distinct] = False
    return distinct


def with_cluster_coordinate(pts: np.ndarray, lab: np.ndarray) -> np.ndarray:
    """(n, p + 1): the points plus their cluster id times a gap > twice the bounding-box diagonal."""
    p = pts.shape[1]
    X = np.empty((len(pts), p + 1))
    X[:, :p] = pts
    lo = pts.min(axis=0)
    hi = pts.max(axis=0)
    gap = 2.0 * float(np.sqrt(((hi - lo) ** 2).sum())) + 1.0
    np.multiply(lab, gap, out=X[:, p])
    return X


def knn_query(g, ginv, rows, kc, threads, query=None, extra=0):
    """k-NN (k = kc[cluster]) of g[rows] among g[rows] of their own cluster.

    ``g`` (n, p) grouped by ascending cluster ids ``ginv``; ``rows`` ascending positions
    in g, each cluster among them with >= k + 2 points; only rows[query] when ``query``
    is given; up to ``extra`` more nearest when the cluster has them. Up to 3
    coordinates: :func:`.kernels.knn.knn_unchecked` (ties lower row first); more:
    :func:`_knn_query_tree`.

    Returns (groups, flagged): one group (k, r (M,), r_k (M,), r_(k+1) (M,), nbx (M,
    k + 1 + e)) per distinct (k, e), the neighbours as positions in g, clusters without
    exact duplicates only; flagged (c,) bool marks clusters with duplicates among the answered.
    """
    if g.shape[1] > 3:
        return _knn_query_tree(g, ginv, rows, kc, threads, query, extra)
    c = len(kc)
    lab = ginv[rows]
    sizes = np.bincount(lab, minlength=c)
    ec = np.clip(sizes - kc - 2, 0, extra) if extra else np.zeros(c, dtype=np.int64)
    qm = None
    if query is not None:
        qm = np.zeros(len(rows), dtype=bool)
        qm[query] = True
    P = g[rows]
    if P.shape[1] < 3:  # zero columns add exactly 0.0 to every squared distance
        P = np.column_stack([P, np.zeros((len(P), 3 - P.shape[1]))])
    indptr = np.zeros(c + 1, dtype=np.int64)
    np.cumsum(sizes, out=indptr[1:])
    kq = np.where(sizes > 0, kc + 1 + ec, 0).astype(np.int64)
    d, i = knn_unchecked(P, indptr, kq, np.ones(len(rows), dtype=bool) if qm is None else qm, threads)
    sel = np.arange(len(rows)) if query is None else np.asarray(query, dtype=np.int64)
    flagged = np.zeros(c, dtype=bool)
    flagged[lab[sel[d[sel, 0] == 0]]] = True  # a copy at distance 0
    key = (kc * (extra + 1) + ec)[lab[sel]]  # (k, e) of each answered point
    keys = np.unique(key)
    whole = len(rows) == len(g)  # rows: all of g, in order (rows[j] == j)
    groups = []
    for kv in keys:
        k, e = divmod(int(kv), extra + 1)
        s = sel if len(keys) == 1 else sel[key == kv]
        s = s[~flagged[lab[s]]]
        if len(s):
            groups.append((k, rows[s], d[s, k - 1], d[s, k], take_neighbours(i, s, k + e + 1, None if whole else rows)))
    return groups, flagged


def _knn_query_tree(g, ginv, rows, kc, threads, query=None, extra=0):
    """:func:`knn_query` with one k-d tree over all clusters (any dimension).

    The cluster coordinate (:func:`with_cluster_coordinate`) puts other clusters
    farther than any own point and adds exactly 0.0 inside one, so distances equal a
    per-cluster tree's.
    """
    c = len(kc)
    lab = ginv[rows]
    X = with_cluster_coordinate(g[rows], lab)
    from scipy.spatial import cKDTree  # here: scipy.spatial's import costs a small run more than its work

    tree = cKDTree(X, leafsize=32, balanced_tree=False, compact_nodes=False)
    ec = np.clip(np.bincount(lab, minlength=c) - kc - 2, 0, extra) if extra else np.zeros(c, dtype=np.int64)
    key = kc * (extra + 1) + ec  # (k, e) of each cluster
    kr = key[lab]
    if query is not None:
        kr = kr[query]
    flagged = np.zeros(c, dtype=bool)
    groups = []
    ks = np.unique(kr)
    for kv in ks:
        k, e = divmod(int(kv), extra + 1)
        sel = None if len(ks) == 1 else np.flatnonzero(kr == kv)
        if query is not None:
            sel = query if sel is None else query[sel]
        # the 2nd to (k+e+2)-th nearest: the nearest is the point itself
        d, i = tree.query(X if sel is None else X[sel], k=list(range(2, k + e + 3)), workers=threads)
        r = rows if sel is None else rows[sel]
        z = d[:, 0] == 0
        if z.any():
            flagged[ginv[r[z]]] = True
            good = ~flagged[ginv[r]]
            r, d, i = r[good], d[good], i[good]
        if len(r):
            nbx = i if len(rows) == len(g) else rows[i]  # rows: all of g, in order
            groups.append((k, r, d[:, k - 1].copy(), d[:, k].copy(), nbx))
        del d
    return groups, flagged


def scorable_rows(g, ginv, sizes, k0, k_min, dup):
    """k per cluster and the rows that get scores (clusters of >= k + 2 points); copies in smaller ones marked in *dup*.

    Returns kc (c,), ok (c,) bool, okr (n,) bool, rows (M,) int.
    """
    kc = neighbour_count(sizes, k0, k_min)
    ok = sizes >= kc + 2
    okr = ok[ginv]
    small = np.flatnonzero(~okr & (sizes[ginv] > 1))
    if len(small):
        mark_duplicates(g, ginv, small, dup)
    return kc, ok, okr, np.flatnonzero(okr)


def knn_clusters(g, ginv, sizes, k0, k_min, threads, extra=0):
    """k-NN of every point inside its own cluster (points g grouped by cluster, ids ginv).

    Returns (groups, dup): groups as :func:`knn_query`; dup (n,) bool marks exact copies.
    """
    n = len(g)
    dup = np.zeros(n, dtype=bool)
    kc, ok, okr, rows = scorable_rows(g, ginv, sizes, k0, k_min, dup)
    if len(rows) == 0:
        return [], dup
    groups, flagged = knn_query(g, ginv, rows, kc, threads, extra=extra)
    if flagged.any():  # score the distinct points of these clusters (m and k follow)
        distinct = mark_duplicates(g, ginv, np.flatnonzero(flagged[ginv]), dup)
        m2 = np.bincount(ginv[distinct], minlength=len(sizes))
        k2 = neighbour_count(m2, k0, k_min)
        rows2 = distinct[(m2 >= k2 + 2)[ginv[distinct]]]
        if len(rows2):
            groups += knn_query(g, ginv, rows2, k2, threads, extra=extra)[0]
    return groups, dup


def knn_context(g, ginv, c, ctx, k0, k_min, threads):
    """k-NN of every point among all points and the context, as :func:`knn_clusters`; a context neighbour is position n."""
    n = len(g)
    pool = np.concatenate([g, ctx]) if len(ctx) else g
    first = _unique_first(pool)  # points come first, so a point wins over a context copy
    is_first = np.zeros(len(pool), dtype=bool)
    is_first[first] = True
    dup = ~is_first[:n]
    upool = pool[first]
    pool_to_g = np.where(first < n, first, n)  # position in g, or n for context
    sizes = np.bincount(ginv[~dup], minlength=c)
    kc = neighbour_count(sizes, k0, k_min)
    ok_cl = sizes >= kc + 2
    pos_in_u = np.full(n, -1, dtype=np.int64)
    pos_in_u[first[first < n]] = np.flatnonzero(first < n)
    cand = np.flatnonzero(~dup & ok_cl[ginv])
    if len(cand) == 0:
        return [], dup
    from scipy.spatial import cKDTree  # here: scipy.spatial's import costs a small run more than its work

    tree = cKDTree(upool, balanced_tree=False, compact_nodes=False)
    kpt = kc[ginv[cand]]
    groups = []
    for k in np.unique(kpt):
        k = int(k)
        sel = cand[kpt == k]
        d, i = tree.query(upool[pos_in_u[sel]], k=list(range(2, k + 3)), workers=threads)  # without itself
        groups.append((k, sel, d[:, k - 1].copy(), d[:, k].copy(), pool_to_g[i]))
    return groups, dup

