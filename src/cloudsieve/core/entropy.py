"""Exact leave-one-out entropy scores of points in their clusters (DESIGN.md stage 4).

For a cluster R of m distinct points, with k = max(k_min, floor(k0*sqrt(m) + 1/2))
fixed for R:

- r_k(x) is the distance from x to its k-th nearest *other* point (the k-th
  smallest value of the multiset of distances, so ties need no rule);
- w(x) = r_k(x)^-d, p(x) = w(x) / W with W = sum_R w (the k-NN density
  k / (m C_d r_k^d) normalised over R: constants and units cancel);
- H(R) = -sum_R p log p = log W - A / W with A = sum_R w log w;
- the score of y is dH(y) = |H(R) - H(R minus y)|, k unchanged.

Removing y deletes y's own term and, for every x whose k nearest include y
(d(x, y) <= r_k(x)), replaces r_k(x) by r_(k+1)(x). With ties this is still
exact: if r_(k+1)(x) = r_k(x) the replacement changes nothing, and if
r_(k+1)(x) > r_k(x) the points at distance <= r_k(x) are exactly the k
nearest the k-d tree returns, whatever order it gives tied points. So one
query of k+1 neighbours per point gives every H(R minus y) in O(m k), computed
without cancellation as::

    H(R - y) - H(R) = log1p(dW / W) - dG / (W + dW)

with dW, dG the changes of W and of G = sum w (log w - A/W).

Duplicates: exact duplicate points of one cluster have r = 0 and no density.
Only the first of each group (lowest index) is scored; the others get the
score 0.0 (a copy of a point that stays is redundant, so every rule drops it)
and are counted in :attr:`Scores.n_duplicates` and logged.

Small clusters: a cluster of fewer than k + 2 distinct points (k_min + 2 at
the default k0) cannot lose a point and keep k neighbours per point; its
points get +inf (always kept).

Context: with ``context=`` (extra points, e.g. a cell's halo, or the whole
cloud around the clusters), r_k(x) is measured among all the points and the
context instead of R alone; H is still summed over R only, and removing y only
changes the terms of R. Context points that coincide with a point are ignored.
An empty context (shape (0, p)) thus means: neighbours from every cluster of
``points``, not from R alone (measured better at equal count in
benchmarks/quality.py).

Speed: without context, all the clusters share one k-d tree (the cluster id
times a gap wider than any cluster as an extra coordinate, which adds exactly
0.0 inside a cluster, so the distances are those of a per-cluster tree), with
the points of each cluster in Z-order, and one threaded query per distinct k.
The k-d tree query is ~80% of the time (cProfile, 1 M points in clusters of
~400, one thread).

Public names: :func:`entropy_scores` (dH per point), :func:`score_points`
(a :class:`Scores` record with dH, the unit-free score m*dH used to pick one
threshold across cells, k, m, the duplicates and the k-NN graph).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InvalidParameterError, InvalidPointsError

__all__ = ["entropy_scores", "score_points", "Scores", "neighbour_count"]

logger = logging.getLogger(__name__)

def neighbour_count(m, k0: float = 1.0, k_min: int = 4):
    """k = max(k_min, floor(k0 * sqrt(m) + 1/2)) for a cluster of m points (array-friendly)."""
    m = np.asarray(m)
    k = np.floor(k0 * np.sqrt(m) + 0.5).astype(np.int64)
    return np.maximum(k, int(k_min))


@dataclass(frozen=True)
class Scores:
    """Scores of every point, in the input order.

    Attributes
    ----------
    delta_h : ndarray of shape (n,), float64
        dH(y) = |H(R) - H(R minus y)|; +inf in clusters too small to score,
        0.0 for the duplicates.
    unit_free : ndarray of shape (n,), float64
        m * dH, m the number of distinct points of the cluster: comparable
        across clusters of different sizes (dH scales as 1/m), so one global
        threshold can be chosen across cells.
    cluster_size : ndarray of shape (n,), int64
        m of the point's cluster (distinct points).
    k : ndarray of shape (n,), int64
        k used for the point's cluster.
    duplicate : ndarray of shape (n,), bool
        True for an exact copy of a lower-index point of the same cluster.
    gain : ndarray of shape (n,), float64
        The signed change H(R minus y) - H(R) (dH is its absolute value):
        > 0 when removing y makes the density of R more uniform. +inf in
        small clusters, 0.0 for duplicates.
    neighbours : ndarray of shape (n, K), int64
        The k-NN graph: row i holds the k nearest of point i (input indices,
        points only, never context), nearest first, padded with -1; rows of
        duplicates and of points in small clusters are all -1. Built on
        first access (the threshold and target rules never need it).
    indptr, indices : ndarray of int64
        The same graph in CSR form (computed on access).
    """

    delta_h: np.ndarray
    unit_free: np.ndarray
    cluster_size: np.ndarray
    k: np.ndarray
    duplicate: np.ndarray
    gain: np.ndarray
    # (order, groups): order maps grouped positions to input indices; groups holds
    # (k, scored grouped positions (M,), neighbours (M, k+1) as grouped positions, n for context)
    _graph: tuple = field(default=(np.zeros(0, dtype=np.int64), ()), repr=False)

    @property
    def n_duplicates(self) -> int:
        return int(self.duplicate.sum())

    @cached_property
    def neighbours(self) -> np.ndarray:
        n = len(self.delta_h)
        out = np.full((n, self.k.max(initial=0)), -1, dtype=np.int64)
        self._graph_into(out, np.arange(n))
        return out

    def _graph_into(self, out: np.ndarray, rows: np.ndarray) -> None:
        """Write the graph into out[rows] (already -1), mapping every index i to rows[i]."""
        order, groups = self._graph
        to = np.append(rows[order], -1)  # grouped position -> rows; n (context) -> -1
        for k, sc, nbx in groups:
            out[to[sc], :k] = to[nbx[:, :k]]

    @property
    def indptr(self) -> np.ndarray:
        out = np.zeros(len(self.neighbours) + 1, dtype=np.int64)
        np.cumsum((self.neighbours >= 0).sum(axis=1), out=out[1:])
        return out

    @property
    def indices(self) -> np.ndarray:
        nb = self.neighbours
        return nb[nb >= 0].astype(np.int64)  # row-major: row by row, nearest first


def _check_points(points, name="points") -> np.ndarray:
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 1:
        raise InvalidParameterError(f"{name} must have shape (n, d), got shape {pts.shape}")
    if not np.issubdtype(pts.dtype, np.number) or np.iscomplexobj(pts):
        raise InvalidParameterError(f"{name} must be real numbers, got dtype {pts.dtype}")
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InvalidPointsError(
            f"{name} has {int(bad.sum())} non-finite (NaN or infinite) rows, the first at index {first}: {pts[first].tolist()}"
        )
    return pts


def _check_labels(labels, n: int) -> np.ndarray:
    if labels is None:
        return np.zeros(n, dtype=np.int64)
    lab = np.asarray(labels)
    if lab.shape != (n,):
        raise InvalidParameterError(f"labels must have shape ({n},) like the points, got shape {lab.shape}")
    if n and not np.issubdtype(lab.dtype, np.integer):
        raise InvalidParameterError(f"labels must be integers, got dtype {lab.dtype}")
    return lab.astype(np.int64, copy=False)


def _check_params(k0, k_min, dim):
    if not (np.isfinite(k0) and k0 > 0):
        raise InvalidParameterError(f"k0 must be a positive number, got {k0!r}")
    if int(k_min) != k_min or k_min < 1:
        raise InvalidParameterError(f"k_min must be an integer >= 1, got {k_min!r}")
    if not (np.isfinite(dim) and dim > 0):
        raise InvalidParameterError(f"dim must be a positive number, got {dim!r}")


def _unique_first(q: np.ndarray) -> np.ndarray:
    """Positions of the first occurrence of each distinct row of q, ascending."""
    order = np.lexsort(q.T[::-1])
    s = q[order]
    new = np.ones(len(q), dtype=bool)
    new[1:] = (s[1:] != s[:-1]).any(axis=1)
    group = np.cumsum(new) - 1
    first = np.full(int(group[-1]) + 1 if len(q) else 0, len(q), dtype=np.int64)
    np.minimum.at(first, group, order)
    return np.sort(first)


def _dense_labels(lab: np.ndarray):
    """Cluster ids 0..c-1 in the order of the label values, and c.

    Small non-negative labels (the usual case) are renumbered with a bincount
    in O(n); others with np.unique (a sort).
    """
    n = len(lab)
    if n == 0:
        return lab.astype(np.int64), 0
    if lab.min() >= 0 and lab.max() < 2 * n + 1024:
        remap = np.cumsum(np.bincount(lab) > 0) - 1
        return remap[lab], int(remap[-1]) + 1
    u, inv = np.unique(lab, return_inverse=True)
    return inv.reshape(-1).astype(np.int64), len(u)


_SPREAD = [(32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
           (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)]


def _morton(pts: np.ndarray, bits: int) -> np.ndarray:
    """Z-order code (uint64) of the first three coordinates, ``bits`` <= 21 bits each over the bounding box.

    Only a row order for memory locality (hand-written: numpy has no Morton
    code); results do not depend on it.
    """
    q = min(pts.shape[1], 3)
    code = np.zeros(len(pts), dtype=np.uint64)
    lo = pts[:, :q].min(axis=0)
    span = float((pts[:, :q].max(axis=0) - lo).max())
    if not (np.isfinite(span) and span > 0):
        return code
    scale = ((1 << bits) - 1) / span
    for j in range(q):
        x = ((pts[:, j] - lo[j]) * scale).astype(np.uint64)
        for s, mask in _SPREAD:
            x |= x << np.uint64(s)
            x &= np.uint64(mask)
        x <<= np.uint64(j)
        code |= x
    return code


def _group(pts: np.ndarray, labels: np.ndarray):
    """Cluster ids 0..c-1, the order grouping the clusters, and the cluster sizes.

    Inside a cluster the rows follow a Z-order curve (exact copies keep their
    input order), so that consecutive k-d tree queries touch the same memory:
    the queries of 1 M points are ~1.5-2x faster than in input order.
    """
    inv, c = _dense_labels(labels)
    bits = min(21, (63 - max(1, (c - 1).bit_length())) // 3)
    key = _morton(pts, bits)
    key |= inv.astype(np.uint64) << np.uint64(3 * bits)
    order = np.argsort(key, kind="stable")
    return inv, order, np.bincount(inv, minlength=c)


def _mark_duplicates(g, ginv, rows, dup):
    """Among g[rows] (grouped by cluster), mark in ``dup`` every exact copy of an
    earlier row of the same cluster; return the other rows, ascending."""
    first = _unique_first(np.column_stack([ginv[rows].astype(np.float64), g[rows]]))
    dup[rows] = True
    distinct = rows[first]
    dup[distinct] = False
    return distinct


def _with_cluster_coordinate(pts: np.ndarray, lab: np.ndarray) -> np.ndarray:
    """(n, p + 1): the points and, as the last coordinate, their cluster id times a
    gap larger than twice the bounding-box diagonal (see :func:`_knn_query`)."""
    p = pts.shape[1]
    X = np.empty((len(pts), p + 1))
    X[:, :p] = pts
    lo = pts.min(axis=0)
    hi = pts.max(axis=0)
    gap = 2.0 * float(np.sqrt(((hi - lo) ** 2).sum())) + 1.0
    np.multiply(lab, gap, out=X[:, p])
    return X


def _knn_query(g, ginv, rows, kc, workers, query=None, extra=0):
    """k-NN (k = kc of the cluster) of the points g[rows] inside their own cluster
    (among g[rows]); only of the points rows[query] when ``query`` (positions in rows) is given.
    With ``extra`` > 0, up to ``extra`` more nearest are returned (as many as the cluster has).

    One k-d tree over all the clusters: each point gets its cluster id times a
    gap as an extra coordinate, the gap larger than twice the bounding-box
    diagonal, so a point of another cluster is always farther than every point
    of the own cluster (a cluster here has >= k + 2 points), and inside a
    cluster the extra term is exactly 0.0: the distances are bit for bit
    those of a tree of the cluster alone. One threaded query per distinct k.

    Returns (groups, flagged): groups as in :func:`_knn_clusters` (with
    ``extra``, the last array has k + 1 + e columns, e <= extra), for the
    clusters without exact duplicates; flagged (c,) bool: clusters with some.
    """
    c = len(kc)
    lab = ginv[rows]
    X = _with_cluster_coordinate(g[rows], lab)
    # leaves of 32: measured ~8% faster queries than 16 (1 M points, k = 20)
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
        # the 2nd to (k+e+2)-th nearest: the nearest is the point itself (the only one at distance 0
        # without copies); k + e + 1 contiguous columns
        d, i = tree.query(X if sel is None else X[sel], k=list(range(2, k + e + 3)), workers=workers)
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


def _knn_clusters(g, ginv, sizes, k0, k_min, workers, extra=0):
    """k-NN of every point inside its own cluster (points g grouped by cluster, ids ginv).

    Returns (groups, dup): groups is a list of (k, scored positions in g (M,),
    r_k (M,), r_(k+1) (M,), the k + 1 nearest (M, k + 1 + e) as positions in
    g, e <= ``extra`` more nearest when the cluster has them); dup (n,) bool
    marks the exact copies (only the first of each is scored).
    """
    n = len(g)
    dup = np.zeros(n, dtype=bool)
    kc = neighbour_count(sizes, k0, k_min)
    ok = sizes >= kc + 2
    okr = ok[ginv]
    small = np.flatnonzero(~okr & (sizes[ginv] > 1))
    if len(small):  # never scored, but their copies still score 0
        _mark_duplicates(g, ginv, small, dup)
    rows = np.flatnonzero(okr)
    if len(rows) == 0:
        return [], dup
    groups, flagged = _knn_query(g, ginv, rows, kc, workers, extra=extra)
    if flagged.any():  # score the distinct points of these clusters (m and k follow)
        distinct = _mark_duplicates(g, ginv, np.flatnonzero(flagged[ginv]), dup)
        m2 = np.bincount(ginv[distinct], minlength=len(sizes))
        k2 = neighbour_count(m2, k0, k_min)
        rows2 = distinct[(m2 >= k2 + 2)[ginv[distinct]]]
        if len(rows2):
            groups += _knn_query(g, ginv, rows2, k2, workers, extra=extra)[0]
    return groups, dup


def score_points(points, labels=None, *, k0: float = 1.0, k_min: int = 4, dim: float = 3,
                 context=None, workers: int | None = None) -> Scores:
    """Leave-one-out entropy scores with the k-NN graph (see the module docstring).

    Parameters
    ----------
    points : array_like of shape (n, p), float
        Coordinates (p = 3 for a cloud; any p works, ``dim`` is the exponent).
    labels : array_like of shape (n,), int, optional
        Cluster of each point (any integers); None: one cluster.
    k0, k_min : float, int
        k = max(k_min, floor(k0*sqrt(m) + 1/2)) per cluster of m points.
    dim : float
        The exponent d of the density r_k^-d (3 for a cloud in space).
    context : array_like of shape (q, p), optional
        Extra density neighbours, never scored.
    workers : int, optional
        Threads for the k-d tree queries (default: all cores).

    Returns
    -------
    Scores
    """
    pts = _check_points(points)
    n = len(pts)
    lab = _check_labels(labels, n)
    _check_params(k0, k_min, dim)
    workers = int(workers or os.cpu_count() or 1)
    if context is not None:
        ctx = _check_points(context, "context")
        if ctx.shape[1] != pts.shape[1]:
            raise InvalidParameterError(
                f"context must have {pts.shape[1]} columns like the points, got shape {ctx.shape}")
    if n == 0:
        z = np.zeros(0)
        zi = np.zeros(0, dtype=np.int64)
        return Scores(z, z.copy(), zi, zi.copy(), np.zeros(0, bool), z.copy())

    inv, order, sizes = _group(pts, lab)
    g = pts[order]  # grouped by cluster
    ginv = inv[order]
    c = len(sizes)
    if context is None:
        groups, dup = _knn_clusters(g, ginv, sizes, k0, k_min, workers)
    else:
        groups, dup = _knn_context(g, ginv, c, ctx, k0, k_min, workers)
    # groups: list of (k, scored positions in g (M,), r_k (M,), r_(k+1) (M,), the k+1 nearest
    # (M, k+1) as positions in g, n for a context point)
    msize = np.bincount(ginv[~dup], minlength=c)  # distinct points per cluster

    dh = np.full(n, np.inf)
    dh[dup] = 0.0
    sg = dh.copy()
    k_in = np.zeros(n, dtype=np.int64)
    if groups:
        scored = np.concatenate([grp[1] for grp in groups])
        rk = np.concatenate([grp[2] for grp in groups])
        rk1 = np.concatenate([grp[3] for grp in groups])
        cl = ginv[scored]
        w, gw, Wc, dw_x, dg_x = _weights(cl, c, rk, rk1, dim)
        acc_w = np.zeros(n + 1)
        acc_g = np.zeros(n + 1)
        ginv_ext = np.append(ginv, -1)
        off = 0
        for k, sc, _, _, nbx in groups:
            M = len(sc)
            tgt = nbx.ravel()  # contiguous: no copy
            # x's change goes to its k nearest; weight 0.0 (adds nothing, exactly) for the (k+1)-th
            rw = np.zeros((M, k + 1))
            rg = np.zeros((M, k + 1))
            rw[:, :k] = dw_x[off : off + M, None]
            rg[:, :k] = dg_x[off : off + M, None]
            if context is not None:  # only neighbours that are scored points of the same cluster count
                other = ginv_ext[nbx] != cl[off : off + M, None]
                rw[other] = 0.0
                rg[other] = 0.0
            acc_w += np.bincount(tgt, weights=rw.ravel(), minlength=n + 1)
            acc_g += np.bincount(tgt, weights=rg.ravel(), minlength=n + 1)
            del rw, rg
            k_in[order[sc]] = k
            off += M
        dH = _change(acc_w[scored] - w, acc_g[scored] - gw, Wc)
        dh[scored] = np.abs(dH)
        sg[scored] = dH

    # back to input order
    out_dh = np.empty(n)
    out_dh[order] = dh
    out_sg = np.empty(n)
    out_sg[order] = sg
    dup_in = np.empty(n, dtype=bool)
    dup_in[order] = dup
    out_m = np.empty(n, dtype=np.int64)
    out_m[order] = msize[ginv]
    with np.errstate(invalid="ignore"):
        unit = out_dh * out_m
    unit[dup_in] = 0.0
    nd = int(dup_in.sum())
    if nd:
        logger.info("%d exact duplicate points scored 0 (redundant copies)", nd)
    graph = (order, tuple((grp[0], grp[1], grp[4]) for grp in groups))
    return Scores(out_dh, unit, out_m, k_in, dup_in, out_sg, graph)


def _weights(cl, c, rk, rk1, dim):
    """Per scored point (cluster ids cl in 0..c-1, r_k, r_(k+1)): w, g = w (log w - A/W), W of its
    cluster, and the changes of w and g when r_k becomes r_(k+1)."""
    # log-weights shifted per cluster so the largest weight is 1 (no overflow, units cancel)
    lr = np.log(rk)
    lr1 = np.log(rk1)
    shift = np.full(c, np.inf)
    np.minimum.at(shift, cl, lr)
    lw = -dim * (lr - shift[cl])
    lw1 = -dim * (lr1 - shift[cl])
    w = np.exp(lw)
    w1 = np.exp(lw1)
    W = np.bincount(cl, weights=w, minlength=c)
    A = np.bincount(cl, weights=w * lw, minlength=c)
    with np.errstate(invalid="ignore", divide="ignore"):
        L = A / W
    gw = w * (lw - L[cl])
    gw1 = w1 * (lw1 - L[cl])
    return w, gw, W[cl], w1 - w, gw1 - gw  # w1 - w is exactly 0 when r_(k+1) = r_k (ties)


def _change(dW, dG, W):
    """H(R minus y) - H(R) from the changes of W and G (no cancellation)."""
    return np.log1p(dW / W) - dG / (W + dW)


def _knn_context(g, ginv, c, ctx, k0, k_min, workers):
    """k-NN of every point among all the points and the context, grouped by k."""
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
    tree = cKDTree(upool, balanced_tree=False, compact_nodes=False)
    kpt = kc[ginv[cand]]
    groups = []
    for k in np.unique(kpt):
        k = int(k)
        sel = cand[kpt == k]
        d, i = tree.query(upool[pos_in_u[sel]], k=list(range(2, k + 3)), workers=workers)  # without itself
        groups.append((k, sel, d[:, k - 1].copy(), d[:, k].copy(), pool_to_g[i]))
    return groups, dup


def entropy_scores(points, labels=None, *, k0: float = 1.0, k_min: int = 4, dim: float = 3,
                   context=None) -> np.ndarray:
    """dH(y) = |H(R) - H(R minus y)| for every point y, R its cluster.

    Parameters
    ----------
    points : array_like of shape (n, p), float
        Coordinates, finite (p = 3 for a cloud).
    labels : array_like of shape (n,), int, optional
        Cluster of each point; None: all points form one cluster.
    k0, k_min : float, int
        k = max(k_min, floor(k0*sqrt(m) + 1/2)) for a cluster of m distinct points.
    dim : float
        Exponent d of the k-NN density r_k^-d (3 in space).
    context : array_like of shape (q, p), optional
        Extra points used only as density neighbours (a cell's halo, the
        cloud around the clusters); None: each cluster alone (the paper).

    Returns
    -------
    ndarray of shape (n,), float64
        The scores, exact (O(m k) per cluster). +inf for the points of clusters
        with fewer than k + 2 distinct points; 0.0 for exact duplicates after
        the first copy (counted and logged; see :func:`score_points`).

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).random((50, 3))
    >>> s = entropy_scores(pts)
    >>> s.shape, bool((s >= 0).all())
    ((50,), True)
    """
    return score_points(points, labels, k0=k0, k_min=k_min, dim=dim, context=context).delta_h
