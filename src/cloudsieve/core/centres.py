"""The k nearest centres of points, for K-means and fuzzy C-means (DESIGN.md stage 3).

:func:`nearest_centres` returns what scipy's ``cKDTree.query`` does, via the
compiled grid search of :mod:`.kernels.centres`; rows with tied k-th distances go
to the tree. Threads: :class:`.kernels.threads.Chunks`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .kernels import centres as kc

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["centre_tree", "cell_size", "ring_grid", "candidate_lists", "no_lists", "nearest_centres"]


def centre_tree(C: np.ndarray) -> cKDTree:
    """The k-d tree over centres C (c, p): the reference of :func:`nearest_centres`."""
    from scipy.spatial import cKDTree  # here: scipy.spatial's import costs a small run more than its work

    return cKDTree(C, balanced_tree=False, compact_nodes=False)


def cell_size(C: np.ndarray, k: int) -> float:
    """Grid side for k-centre queries: median distance to the k-th nearest other centre (512 sampled)."""
    c = len(C)
    S = C[:: max(1, c // 512)]
    d = centre_tree(C).query(S, k=min(k + 1, c))[0]
    h = float(np.median(d.reshape(len(S), -1)[:, -1]))
    if not h > 0:  # duplicate centres: the extent shared among them
        ext = np.ptp(C[:, :3], axis=0)
        ext = ext[ext > 0]
        h = float(np.prod(ext) ** (1 / len(ext)) * c ** (-1 / len(ext))) if len(ext) else 1.0
    return h


_MAX_CELLS_PER_CENTRE = 8


def ring_grid(C: np.ndarray, h: float) -> tuple:
    """The ``ring`` tuple of :mod:`.kernels.centres`: a grid over C of side about h (coarser if too many cells)."""
    c, p = C.shape
    q = min(p, 3)
    lo = np.zeros(3)
    lo[:q] = C[:, :q].min(axis=0)
    ext = np.zeros(3)
    ext[:q] = C[:, :q].max(axis=0) - lo[:q]
    while True:
        dims = (np.floor(ext / h) + 1).astype(np.int64)
        if float(np.prod(dims.astype(np.float64))) <= _MAX_CELLS_PER_CENTRE * c + 64:
            break
        h *= 1.5
    cell = kc.grid_cells(C, lo, h, dims)
    order = np.argsort(cell, kind="stable")
    start = np.searchsorted(cell[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
    margin = 1e-12 * (float(np.abs(lo).max()) + float((dims * h).max()))
    return np.ascontiguousarray(C[order]), order.astype(np.int64), start, lo, float(h), dims, margin


def no_lists(p: int) -> tuple:
    """The ``lists`` tuple of :mod:`.kernels.centres` that holds no lists (ring search only)."""
    z = np.zeros(0, dtype=np.int64)
    return np.zeros(3), 1.0, np.ones(3, dtype=np.int64), z, z, z.astype(np.int32), np.zeros((0, p))


_FINE = 4  # fine cells per grid cell along an axis, at most
_MIN_POINTS_PER_LIST = 16  # fewer points per occupied fine cell: a coarser fine grid (16, 48: alike on surfaces;
# 16 faster in volumes)


def candidate_lists(X, rows, C, ring, k, chunks) -> tuple:
    """The ``lists`` tuple of :mod:`.kernels.centres`: candidate lists of the fine cells holding X[rows].

    Fine side h / ``_FINE``, halved while occupied fine cells hold fewer than
    ``_MIN_POINTS_PER_LIST`` points. Only speed depends on it.
    """
    lo, h, dims = ring[3], ring[4], ring[5]
    m = len(rows)
    M = _FINE
    while True:
        fdims = dims * M
        n_cells = int(np.prod(fdims))
        if n_cells <= 4 * m + 4096 or M == 1:
            occupied = np.zeros(n_cells, dtype=np.uint8)
            s = h / M
            chunks.map(lambda a, b: kc.fine_cells(X, rows, a, b, lo, s, fdims, occupied), m)
            cells = np.flatnonzero(occupied).astype(np.int64)
            if M == 1 or m >= _MIN_POINTS_PER_LIST * len(cells):
                break
        M //= 2
    parts = chunks.map(lambda a, b: kc.cell_candidates(cells, a, b, ring, lo, s, fdims, k), len(cells), min_chunk=256)
    counts = np.concatenate([c for c, _ in parts])
    lids = np.concatenate([i for _, i in parts])
    cellpos = np.full(n_cells, -1, dtype=np.int64)
    cellpos[cells] = np.arange(len(cells))
    lstart = np.zeros(len(cells) + 1, dtype=np.int64)
    np.cumsum(counts, out=lstart[1:])
    return lo, float(s), fdims, cellpos, lstart, lids.astype(np.int32), C


_LIST_MIN_ROWS_PER_CENTRE = 16  # fewer query points than this per centre: rings only


def nearest_centres(X, C, k, chunks, h, rows=None):
    """The k nearest centres (1 <= k <= c) of X[rows] (all when None): (distances, indices), each (m, k), ascending.

    Equal to ``centre_tree(C).query(X[rows], k)``, except the last column's index on
    a tie with a centre not returned (K-means and FCM use only its distance).
    ``chunks``: :class:`.kernels.threads.Chunks`; ``h``: grid side (:func:`cell_size`),
    only speed depends on it.
    """
    if rows is None:
        rows = np.arange(len(X), dtype=np.int64)
    m = len(rows)
    d = np.empty((m, k))
    i = np.empty((m, k), dtype=np.int64)
    tie = np.empty(m, dtype=np.uint8)
    if m == 0:
        return d, i
    ring = ring_grid(C, h)
    use_lists = X.shape[1] <= 3 and m >= _LIST_MIN_ROWS_PER_CENTRE * len(C)
    lists = candidate_lists(X, rows, C, ring, k, chunks) if use_lists else no_lists(X.shape[1])
    chunks.map(lambda s, e: kc.nearest_centres(X, rows, s, e, ring, lists, k, d, i, tie), m, min_chunk=1024)
    t = np.flatnonzero(tie)
    if len(t):
        w = chunks.threads if len(t) >= 20_000 else 1
        dt, it = centre_tree(C).query(X[rows[t]], k=k, workers=w)
        d[t] = dt.reshape(len(t), k)
        i[t] = it.reshape(len(t), k)
    return d, i
