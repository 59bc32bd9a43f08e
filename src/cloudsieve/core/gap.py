"""The gap bound (``max_gap``) on one cell: the fill after the elimination (:func:`fill_cell`) and the
exact check (:func:`cell_gap`); docs/architecture.md, "The gap bound".

The kept set only grows after a cell's fill, so every point of the cell ends
within D of the kept set whatever its neighbours add.
"""

from __future__ import annotations

import numpy as np

__all__ = ["fill_cell", "cell_gap"]


def _nearest(kept, points: np.ndarray, bound: float = np.inf) -> np.ndarray:
    """Distance (n,) from each of *points* to the nearest of *kept* ((k, 3), or :func:`_tree`'s; inf beyond
    *bound* or with none)."""
    if not len(points):
        return np.zeros(0)
    tree = _tree(kept)
    if tree is None:
        return np.full(len(points), np.inf)
    return tree.query(points, distance_upper_bound=bound)[0]


def _tree(kept):
    """A k-d tree of the points *kept* (k, 3), None for none; a tree (or None) is returned as it is."""
    from scipy.spatial import cKDTree

    if kept is None or isinstance(kept, cKDTree):
        return kept
    return cKDTree(kept) if len(kept) else None


def fill_cell(core: np.ndarray, keep: np.ndarray, known: np.ndarray, gap: float, keep_duplicates: bool) -> np.ndarray:
    """The points of *core* (n, 3) to add to *keep* (n,) so that each lies within *gap* of the kept set: (n,) bool.

    *known*: the other kept points (h, 3) the cell can see (its halo's final
    ones). With *keep_duplicates*, every copy of an added point is added.
    """
    from .kernels.gapfill import greedy_cover

    n = len(core)
    fill = np.zeros(n, dtype=bool)
    kept = np.concatenate([core[keep], known]) if len(known) else core[keep]
    tree = _tree(kept)  # built once for both queries
    far = np.flatnonzero(_nearest(tree, core, gap) > gap)
    if not len(far):
        return fill
    d = _nearest(tree, core[far])  # exact, for the order: farthest first, ties by row
    far = far[np.lexsort((far, -d))]
    pts = np.ascontiguousarray(core[far], dtype=np.float64)
    q = np.floor((pts - pts.min(axis=0)) / gap).astype(np.int64)
    u, cell = np.unique(q, axis=0, return_inverse=True)
    fill[far[greedy_cover(pts, q, cell.reshape(-1).astype(np.int64), u, float(gap))]] = True
    # the k-d tree's distances decide: a point it still finds farther than D is added too (rounding)
    rest = far[~fill[far]]
    if len(rest):
        fill[rest[_nearest(np.concatenate([kept, core[fill]]), core[rest], gap) > gap]] = True
    if keep_duplicates:
        from .duplicates import first_copies

        first = first_copies(core)
        marked = np.zeros(n, dtype=bool)
        marked[first[fill]] = True
        fill = marked[first] & ~keep
    return fill


def cell_gap(core: np.ndarray, kept: np.ndarray, bound: float = np.inf) -> float:
    """The largest distance from a point of *core* (n, 3) to the nearest of *kept* (k, 3); 0 for no point.

    inf when a point has none within *bound* (a faster search)."""
    return float(_nearest(kept, core, bound).max()) if len(core) else 0.0
