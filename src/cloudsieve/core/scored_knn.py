"""The k nearest inside clusters as the scores without context need them (DESIGN.md stage 4).

The scored layout, shared by :mod:`.kernels.knn` and :mod:`.kernels.entropy`: points
in input order with ``order`` (input indices grouped by cluster) and ``indptr``
(c + 1,) cluster starts; per grouped position ``rk``, ``rk1`` (r_k, r_(k+1)) and
``scored``; per cluster k ``kcl`` (0: not scored) and ``koff`` (c + 1,); the k nearest
of scored position p of cluster j (grouped positions, nearest first) at
``nb[koff[j] + (p - indptr[j]) * k]``, k entries.

:func:`knn_scored_clusters` fills it (:func:`.kernels.knn.knn_scored`);
:func:`groups_to_lists` writes :func:`.knn.knn_clusters`' groups into it.
"""

from __future__ import annotations

import numpy as np

from ._validation import neighbour_count
from .duplicates import copy_rows
from .kernels.knn import knn_scored
from .knn import knn_query, mark_duplicates

__all__ = ["knn_scored_clusters", "groups_to_lists"]


def _cluster_of(indptr, rows):
    """Cluster id of grouped positions ``rows``."""
    return np.searchsorted(indptr, rows, side="right") - 1


_LARGE = 2048  # points of a cluster above which its exact copies are looked for before its k-NN


def _copies(pts, order, indptr, rows, dup):
    """:func:`.knn.mark_duplicates` of ascending grouped positions ``rows``, points read through order."""
    sub = np.ascontiguousarray(pts[order[rows]])
    local = np.zeros(len(rows), dtype=bool)
    first = mark_duplicates(sub, _cluster_of(indptr, rows), np.arange(len(rows)), local)
    dup[rows] = local
    return rows[first]


def knn_scored_clusters(pts, order, indptr, k0, k_min, threads):
    """k-NN of every point inside its own cluster in the scored layout (module docstring; 1 to 3 coordinates).

    ``order``, ``indptr`` from :func:`.knn.group`; ``k0, k_min, threads`` as
    :func:`.knn.knn_clusters`. Clusters with copies are redone by :func:`.knn.knn_query`
    on their distinct points. Returns rk, rk1 (1.0 where not scored), kcl, koff,
    scored, nb, and dup (n,) bool, the exact copies.
    """
    n = len(order)
    sizes = np.diff(indptr)
    kc = neighbour_count(sizes, k0, k_min)
    ok = sizes >= kc + 2
    dup = np.zeros(n, dtype=bool)
    small = np.flatnonzero(~ok & (sizes > 1))
    if len(small):  # their copies score 0, the other points +inf
        _copies(pts, order, indptr, np.concatenate([np.arange(indptr[j], indptr[j + 1]) for j in small]), dup)
    kcl = np.where(ok, kc, 0).astype(np.int64)
    koff = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes * kcl, out=koff[1:])
    # the kernel flags copies only after its k-NN search, where a pile of m copies costs m^2:
    # large clusters are checked first, by hashing
    big = np.flatnonzero((kcl > 0) & (sizes > _LARGE))
    pre = np.zeros(len(sizes), dtype=bool)
    if len(big):
        rows = np.concatenate([np.arange(indptr[j], indptr[j + 1]) for j in big])
        key = np.column_stack([pts[order[rows]], _cluster_of(indptr, rows).astype(np.float64)])
        pre[np.unique(_cluster_of(indptr, rows[copy_rows(key)]))] = True
    rk, rk1, nb, flag = knn_scored(pts, order, indptr, np.where(pre, 0, kcl), koff, threads)
    flag |= pre
    if flag.any():  # score the distinct points of these clusters (m and k follow)
        kcl[flag] = 0
        fl = np.flatnonzero(flag)
        rows = np.concatenate([np.arange(indptr[j], indptr[j + 1]) for j in fl])
        distinct = _copies(pts, order, indptr, rows, dup)
        cl = _cluster_of(indptr, distinct)
        m2 = np.bincount(cl, minlength=len(sizes))
        k2 = neighbour_count(m2, k0, k_min)
        rows2 = distinct[(m2 >= k2 + 2)[cl]]
        if len(rows2):
            sub = np.ascontiguousarray(pts[order[rows2]])
            groups = knn_query(sub, _cluster_of(indptr, rows2), np.arange(len(rows2)), k2, threads)[0]
            groups = [(k, rows2[r], a, b, rows2[i]) for k, r, a, b, i in groups]
            groups_to_lists(groups, indptr, kcl, koff, rk, rk1, nb)
    scored = (kcl > 0)[np.repeat(np.arange(len(sizes)), sizes)] & ~dup
    return rk, rk1, kcl, koff, scored, nb, dup


def groups_to_lists(groups, indptr, kcl, koff, rk, rk1, nb):
    """Write :func:`.knn.knn_clusters` groups into the layout of :func:`knn_scored_clusters`, in place; kcl gets each group's k."""
    for k, r, a, b, nbx in groups:
        cl = _cluster_of(indptr, r)
        kcl[cl] = k
        rk[r] = a
        rk1[r] = b
        at = koff[cl] + (r - indptr[cl]) * k
        nb[at[:, None] + np.arange(k)] = nbx[:, :k]
