"""Exact leave-one-out entropy scores of points in their clusters (DESIGN.md stage 4).

For a cluster R of m distinct points, k = max(k_min, floor(k0*sqrt(m) + 1/2)):

- r_k(x): distance from x to its k-th nearest *other* point;
- w(x) = r_k(x)^-d, p(x) = w(x) / W, W = sum_R w (constants and units cancel);
- H(R) = -sum_R p log p = log W - A / W, A = sum_R w log w;
- score dH(y) = |H(R) - H(R minus y)|, k unchanged.

Removing y replaces r_k(x) by r_(k+1)(x) for every x with d(x, y) <= r_k(x);
exact with ties too. One (k+1)-NN query per point gives every H(R minus y) in
O(m k), without cancellation, as::

    H(R - y) - H(R) = log1p(dW / W) - dG / (W + dW)

with dW, dG the changes of W and of G = sum w (log w - A/W).

Exact duplicates in a cluster: only the first is scored, the others get 0.0
(:attr:`Scores.n_duplicates`). A cluster of fewer than k + 2 distinct points
gets +inf (always kept).

``context=`` (extra points, e.g. a cell's halo): r_k(x) is measured among the
points and the context; H is summed over R only. An empty context means
neighbours from every cluster of ``points``, not R alone.

Neighbours: :mod:`.kernels.knn` without context, scipy's cKDTree with it;
W/A terms and reverse-neighbour sums: :mod:`.kernels.entropy`.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ._validation import check_context, check_labels, check_points
from ..params import validate_params
from .kernels.entropy import grouped_gain, graph_to_input, scores_to_input
from .knn import group, knn_clusters, knn_context
from .scored_knn import groups_to_lists, knn_scored_clusters

__all__ = ["entropy_scores", "score_points", "Scores", "score_unchecked", "entropy_change"]

logger = logging.getLogger(__name__)

@dataclass(frozen=True)
class Scores:
    """Scores of every point, in the input order; arrays of shape (n,) unless noted.

    Attributes
    ----------
    delta_h : float64
        dH(y); +inf in clusters too small to score, 0.0 for duplicates.
    unit_free : float64
        m * dH (m: distinct points of the cluster): comparable across cluster sizes.
    cluster_size, k : int64
        m and k of the point's cluster.
    duplicate : bool
        Exact copy of a lower-index point of the same cluster.
    gain : float64
        Signed H(R minus y) - H(R); +inf in small clusters, 0.0 for duplicates.
    neighbours : ndarray (n, K), int64
        k-NN graph, input indices, nearest first, padded with -1 (rows of duplicates
        and small clusters all -1); built on first access.
    indptr, indices : int64
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


@validate_params("scores")
def score_points(points, labels=None, *, k0: float = 1.0, k_min: int = 4, dim: float = 3,
                 context=None, threads: int | None = None) -> Scores:
    """Leave-one-out entropy scores with the k-NN graph (see the module docstring).

    Parameters
    ----------
    points : array_like of shape (n, p), float
    labels : array_like of shape (n,), int, optional
        Cluster of each point; None: one cluster.
    k0, k_min : float, int
        k = max(k_min, floor(k0*sqrt(m) + 1/2)) per cluster of m points.
    dim : float
        Exponent d of the density r_k^-d.
    context : array_like of shape (q, p), optional
        Extra density neighbours, never scored.
    threads : int, optional
        Default: all cores.

    Returns
    -------
    Scores
    """
    pts = check_points(points)
    lab = check_labels(labels, len(pts))
    ctx = check_context(context, pts.shape[1])
    return score_unchecked(pts, lab, k0, k_min, dim, ctx, threads)


def score_unchecked(pts, lab, k0, k_min, dim, ctx, threads) -> Scores:
    """:func:`score_points` on validated input (no checks, no copy); ``threads`` None: all cores."""
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
        # groups: (k, scored positions in g, r_k, r_(k+1), the k+1 nearest as positions in g (n: context))
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

    Parameters as :func:`score_points`; ``context`` None: each cluster alone (the paper).
    Returns float64 (n,): +inf in clusters of fewer than k + 2 distinct points, 0.0
    for duplicates after the first.

    >>> import numpy as np
    >>> s = entropy_scores(np.random.default_rng(0).random((50, 3)))
    >>> s.shape, bool((s >= 0).all())
    ((50,), True)
    """
    return score_points(points, labels, k0=k0, k_min=k_min, dim=dim, context=context).delta_h  # validated there
