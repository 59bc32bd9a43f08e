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

Public names: :func:`entropy_scores` (dH per point), :func:`score_points`
(a :class:`Scores` record with dH, the unit-free score m*dH used to pick one
threshold across cells, k, m, the duplicates and the k-NN graph).
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .errors import InvalidParameterError, InvalidPointsError

__all__ = ["entropy_scores", "score_points", "Scores", "neighbour_count"]

logger = logging.getLogger(__name__)

# Clusters at least this large are queried with a multi-threaded k-d tree query;
# smaller ones are spread over a thread pool, one cluster per task.
_BIG_CLUSTER = 50_000


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
        duplicates and of points in small clusters are all -1.
    indptr, indices : ndarray of int64
        The same graph in CSR form (computed on access).
    """

    delta_h: np.ndarray
    unit_free: np.ndarray
    cluster_size: np.ndarray
    k: np.ndarray
    duplicate: np.ndarray
    neighbours: np.ndarray
    gain: np.ndarray

    @property
    def n_duplicates(self) -> int:
        return int(self.duplicate.sum())

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


def _cluster_knn(q: np.ndarray, k0, k_min, workers: int):
    """k-NN inside one cluster q (m, d).

    Returns (keep, k, rk, rk1, nbr): keep = local positions of the distinct points
    (None when all are distinct), and for the distinct points r_k, r_(k+1) and
    their k nearest (positions in q). k = 0 and empty arrays for a small cluster.
    """
    m = len(q)
    keep = None
    k = int(neighbour_count(m, k0, k_min))
    if m < k + 2:
        if m > 1:
            u = _unique_first(q)
            keep = u if len(u) < m else None
        return keep, 0, None, None, None
    tree = cKDTree(q, balanced_tree=False, compact_nodes=False)
    d, i = tree.query(q, k=k + 2, workers=workers)
    if (d[:, 1] == 0).any():  # exact duplicates: score the distinct points only
        u = _unique_first(q)
        keep = u
        q = q[u]
        m = len(q)
        k = int(neighbour_count(m, k0, k_min))
        if m < k + 2:
            return keep, 0, None, None, None
        tree = cKDTree(q, balanced_tree=False, compact_nodes=False)
        d, i = tree.query(q, k=k + 2, workers=workers)
        i = u[i]  # back to positions in the original q
    # column 0 is the point itself (the only one at distance 0)
    return keep, k, d[:, k], d[:, k + 1], i[:, 1 : k + 1]


def _group(labels: np.ndarray):
    """Cluster ids 0..c-1, the stable order grouping them, and the group bounds."""
    _, inv = np.unique(labels, return_inverse=True)
    inv = inv.reshape(-1).astype(np.int64)
    order = np.argsort(inv, kind="stable")
    counts = np.bincount(inv)
    bounds = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=bounds[1:])
    return inv, order, bounds


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
        return Scores(z, z.copy(), zi, zi.copy(), np.zeros(0, bool), np.zeros((0, 0), np.int64), z.copy())

    inv, order, bounds = _group(lab)
    g = pts[order]  # grouped by cluster, stable
    ginv = inv[order]
    c = len(bounds) - 1
    if context is None:
        groups, dup = _knn_clusters(g, bounds, k0, k_min, workers)
    else:
        groups, dup = _knn_context(g, ginv, bounds, ctx, k0, k_min, workers)
    # groups: list of (k, scored positions in g (M,), r_k (M,), r_(k+1) (M,), k nearest (M, k) as
    # positions in g, n for a context point)
    msize = np.bincount(ginv[~dup], minlength=c)  # distinct points per cluster

    dh = np.full(n, np.inf)
    dh[dup] = 0.0
    sg = dh.copy()
    K = max((grp[0] for grp in groups), default=0)
    nb_in = np.full((n, K), -1, dtype=np.int64)
    k_in = np.zeros(n, dtype=np.int64)
    if groups:
        scored = np.concatenate([grp[1] for grp in groups])
        kk = np.concatenate([np.full(len(grp[1]), grp[0], dtype=np.int64) for grp in groups])
        rk = np.concatenate([grp[2] for grp in groups])
        rk1 = np.concatenate([grp[3] for grp in groups])
        cl = ginv[scored]
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
        dw_x = w1 - w  # exactly 0 when r_(k+1) = r_k (ties)
        dg_x = gw1 - gw
        acc_w = np.zeros(n + 1)
        acc_g = np.zeros(n + 1)
        ginv_ext = np.append(ginv, -1)
        order_ext = np.append(order, -1)
        off = 0
        for k, sc, _, _, nbr in groups:
            M = len(sc)
            tgt = nbr.ravel()
            rw = np.repeat(dw_x[off : off + M], k)
            rg = np.repeat(dg_x[off : off + M], k)
            if context is not None:  # only neighbours that are scored points of the same cluster count
                other = ginv_ext[tgt] != np.repeat(cl[off : off + M], k)
                rw[other] = 0.0
                rg[other] = 0.0
            acc_w += np.bincount(tgt, weights=rw, minlength=n + 1)
            acc_g += np.bincount(tgt, weights=rg, minlength=n + 1)
            rows = order[sc]
            nb_in[rows, :k] = order_ext[nbr]
            k_in[rows] = k
            off += M
        dW = acc_w[scored] - w
        dG = acc_g[scored] - gw
        Wc = W[cl]
        dH = np.log1p(dW / Wc) - dG / (Wc + dW)
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
    return Scores(out_dh, unit, out_m, k_in, dup_in, nb_in, out_sg)


def _knn_clusters(g, bounds, k0, k_min, workers):
    """k-NN of every point inside its own cluster (grouped points g), grouped by k."""
    n = len(g)
    c = len(bounds) - 1
    sizes = np.diff(bounds)
    results: list = [None] * c

    def run(j, w=1):
        a, b = bounds[j], bounds[j + 1]
        results[j] = _cluster_knn(g[a:b], k0, k_min, w)

    big = np.flatnonzero(sizes >= _BIG_CLUSTER)
    small = np.flatnonzero(sizes < _BIG_CLUSTER)
    for j in big:
        run(j, workers)
    if workers > 1 and len(small) >= 4 * workers:
        with ThreadPoolExecutor(workers) as ex:
            list(ex.map(run, small, chunksize=max(1, len(small) // (8 * workers))))
    else:
        for j in small:
            run(j)
    dup = np.zeros(n, dtype=bool)
    byk: dict = {}
    for j in range(c):
        keep, k, r_k, r_k1, nbr = results[j]
        a, b = bounds[j], bounds[j + 1]
        if keep is not None:
            dup[a:b] = True
            dup[a + keep] = False
            loc = keep
        else:
            loc = np.arange(b - a)
        if k:
            byk.setdefault(k, []).append((a + loc, r_k, r_k1, a + nbr))
    groups = []
    for k in sorted(byk):
        parts = byk[k]
        groups.append((k, np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                       np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts])))
    return groups, dup


def _knn_context(g, ginv, bounds, ctx, k0, k_min, workers):
    """k-NN of every point among all the points and the context, grouped by k."""
    n = len(g)
    pool = np.concatenate([g, ctx]) if len(ctx) else g
    first = _unique_first(pool)  # points come first, so a point wins over a context copy
    is_first = np.zeros(len(pool), dtype=bool)
    is_first[first] = True
    dup = ~is_first[:n]
    upool = pool[first]
    pool_to_g = np.where(first < n, first, n)  # position in g, or n for context
    sizes = np.bincount(ginv[~dup], minlength=len(bounds) - 1)
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
        d, i = tree.query(upool[pos_in_u[sel]], k=k + 2, workers=workers)
        groups.append((k, sel, d[:, k], d[:, k + 1], pool_to_g[i[:, 1 : k + 1]]))
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
