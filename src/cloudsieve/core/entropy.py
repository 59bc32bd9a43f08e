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

Speed: without context, the k nearest come from the compiled kernel of
:mod:`.kernels.knn` (a small k-d tree per cluster, the clusters shared among
``threads`` threads; the distances of a k-d tree, bit for bit), with the
points of each cluster in Z-order; the W/A terms and the reverse-neighbour
sums from :mod:`.kernels.entropy` (the same values, bit for bit, as the
numpy code they replace). With a context, the neighbours come from scipy's
cKDTree over the points and the context.

(:mod:`.knn` and :mod:`.scored_knn` hold the k-NN queries.)

Public names: :func:`entropy_scores` (dH per point), :func:`score_points`
(a :class:`Scores` record with dH, the unit-free score m*dH used to pick one
threshold across cells, k, m, the duplicates and the k-NN graph); for the other
core modules, on validated input: :func:`score_unchecked` (the kernel behind
:func:`score_points`) and :func:`entropy_change` (dH from the W/A terms of
:func:`.kernels.entropy.entropy_weights`).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ._validation import check_context, check_density_params, check_labels, check_points
from .kernels.entropy import grouped_gain, graph_to_input, scores_to_input
from .knn import group, knn_clusters, knn_context
from .scored_knn import groups_to_lists, knn_scored_clusters

__all__ = ["entropy_scores", "score_points", "Scores", "score_unchecked", "entropy_change"]

logger = logging.getLogger(__name__)

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
    # (order, indptr, kcl, koff, scored, nb) of .scored_knn.knn_scored_clusters: order maps grouped
    # positions to input indices; nb holds the k nearest of the scored positions (n for context)
    _graph: tuple | None = field(default=None, repr=False)

    @property
    def n_duplicates(self) -> int:
        return int(self.duplicate.sum())

    @cached_property
    def neighbours(self) -> np.ndarray:
        width = self.k.max(initial=0)
        if self._graph is None:
            return np.full((len(self.delta_h), width), -1, dtype=np.int64)
        return graph_to_input(*self._graph, width)

    @property
    def indptr(self) -> np.ndarray:
        out = np.zeros(len(self.neighbours) + 1, dtype=np.int64)
        np.cumsum((self.neighbours >= 0).sum(axis=1), out=out[1:])
        return out

    @property
    def indices(self) -> np.ndarray:
        nb = self.neighbours
        return nb[nb >= 0].astype(np.int64)  # row-major: row by row, nearest first


def score_points(points, labels=None, *, k0: float = 1.0, k_min: int = 4, dim: float = 3,
                 context=None, threads: int | None = None) -> Scores:
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
    threads : int, optional
        Threads for the k-d tree queries (default: all cores).

    Returns
    -------
    Scores
    """
    pts = check_points(points)
    lab = check_labels(labels, len(pts))
    check_density_params(k0, k_min, dim)
    ctx = check_context(context, pts.shape[1])
    return score_unchecked(pts, lab, k0, k_min, dim, ctx, threads)


def score_unchecked(pts, lab, k0, k_min, dim, ctx, threads) -> Scores:
    """:func:`score_points` on validated input (no checks, no copy of the points).

    Parameters
    ----------
    pts : ndarray of shape (n, p), float64, finite
    lab : ndarray of shape (n,), int64
    k0, k_min, dim : float, int, float
        Valid (see :func:`._validation.check_density_params`).
    ctx : ndarray of shape (q, p), float64, finite, or None
    threads : int or None
        None: all cores.

    Returns
    -------
    Scores
    """
    n = len(pts)
    threads = int(threads or os.cpu_count() or 1)
    if n == 0:
        z = np.zeros(0)
        zi = np.zeros(0, dtype=np.int64)
        return Scores(z, z.copy(), zi, zi.copy(), np.zeros(0, bool), z.copy())

    inv, order, sizes = group(pts, lab)
    c = len(sizes)
    indptr = np.zeros(c + 1, dtype=np.int64)
    np.cumsum(sizes, out=indptr[1:])
    if ctx is None and pts.shape[1] <= 3:
        rk, rk1, kcl, koff, scored, nb, dup = knn_scored_clusters(pts, order, indptr, k0, k_min, threads)
    else:
        g = pts[order]  # grouped by cluster
        ginv = inv[order]
        if ctx is None:
            groups, dup = knn_clusters(g, ginv, sizes, k0, k_min, threads)
        else:
            groups, dup = knn_context(g, ginv, c, ctx, k0, k_min, threads)
        del g
        # groups: (k, scored positions in g (M,), r_k (M,), r_(k+1) (M,), the k+1 nearest (M, k+1)
        # as positions in g, n for a context point); one k per cluster
        kcl = np.zeros(c, dtype=np.int64)
        scored = np.zeros(n, dtype=bool)
        for grp in groups:
            kcl[ginv[grp[1]]] = grp[0]
            scored[grp[1]] = True
        koff = np.zeros(c + 1, dtype=np.int64)
        np.cumsum(sizes * kcl, out=koff[1:])
        rk = np.ones(n)
        rk1 = np.ones(n)
        nb = np.empty(int(koff[-1]), dtype=np.int64)
        groups_to_lists(groups, indptr, kcl, koff, rk, rk1, nb)
        del groups
    gain = grouped_gain(rk, rk1, indptr, kcl, koff, scored, nb, dim)
    del rk, rk1
    msize = sizes - np.bincount(np.searchsorted(indptr, np.flatnonzero(dup), side="right") - 1, minlength=c)
    dh, unit, sg, m_in, k_in, dup_in = scores_to_input(order, indptr, kcl, scored, dup, msize, gain)
    nd = int(dup.sum())
    if nd:
        logger.info("%d exact duplicate points scored 0 (redundant copies)", nd)
    return Scores(dh, unit, m_in, k_in, dup_in, sg, (order, indptr, kcl, koff, scored, nb))


def entropy_change(dW, dG, W):
    """H(R minus y) - H(R) from the changes of W and G (no cancellation); arrays of shape (M,)."""
    return np.log1p(dW / W) - dG / (W + dW)


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
