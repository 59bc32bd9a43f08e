"""The COPC octree on numpy arrays: cube, node keys, and which node keeps each point.

Node ``(d, i, j, k)`` is cell ``(i, j, k)`` of the root cube cut into ``2^d``
per axis; a point's cell at depth d is its cell at :data:`KEY_DEPTH` shifted
right, so one Morton key per point (:func:`point_keys`) gives its node and
voxel at every depth. :func:`assign_levels` follows Untwine and PDAL's
``writers.copc``: a node of at most *leaf_points* points keeps them all;
another keeps the first point of each voxel of its ``2^GRID_BITS``-per-axis
grid and passes the rest down. Given a rank per point (``cloudsieve_rank``,
0 the most important), a voxel keeps its point of lowest rank instead (ties
by position), so the coarse levels hold the points an elimination kept
longest. A subtree depends on its own points only
(:func:`cloudsieve.store.copc.export_copc` relies on it).
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRID_BITS", "MAX_DEPTH", "KEY_DEPTH", "root_cube", "cells", "morton", "demorton", "point_keys",
           "node_keys", "assign_levels", "group_nodes"]

#: voxels of a node's sampling grid along each axis: 2^GRID_BITS (as Untwine and PDAL)
GRID_BITS = 7
#: deepest node; its voxels (cells at depth MAX_DEPTH + GRID_BITS = 21) pack into 63 bits
MAX_DEPTH = 14
#: depth of the cells whose Morton keys (:func:`point_keys`) give every node and voxel of a point
KEY_DEPTH = MAX_DEPTH + GRID_BITS


def root_cube(bounds: np.ndarray) -> tuple[np.ndarray, float]:
    """The root cube around *bounds* (2, 3): its lowest corner (3,) and its edge.

    The corner is the bounds' minimum, as PDAL writes and copc-lib expects;
    the edge is the largest extent (1.0 for a single position).
    """
    bounds = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(bounds)):
        bounds = np.zeros((2, 3))
    size = float(np.max(bounds[1] - bounds[0]))
    if not size > 0:
        size = 1.0
    return bounds[0].copy(), size


def cells(xyz: np.ndarray, origin: np.ndarray, size: float, depth: int) -> np.ndarray:
    """Cell of each point at *depth*: ndarray of shape (n, 3), int64, each in ``[0, 2^depth)``."""
    n = 1 << depth
    c = np.floor((np.asarray(xyz, dtype=np.float64) - origin) * (float(n) / size))
    np.clip(c, 0, n - 1, out=c)
    return c.astype(np.int64)


def _spread(v: np.ndarray) -> np.ndarray:
    """The bits of *v* (at most 21) moved to every third position."""
    v = v.astype(np.int64) & 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


def _squeeze(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_spread`."""
    v = v & 0x1249249249249249
    v = (v | (v >> 2)) & 0x10C30C30C30C30C3
    v = (v | (v >> 4)) & 0x100F00F00F00F00F
    v = (v | (v >> 8)) & 0x1F0000FF0000FF
    v = (v | (v >> 16)) & 0x1F00000000FFFF
    v = (v | (v >> 32)) & 0x1FFFFF
    return v


def morton(c: np.ndarray) -> np.ndarray:
    """Morton (Z-order) keys (n,) int64 of cells (n, 3) of at most 21 bits each.

    Cell m at depth d has the descendants ``[m << 3e, (m + 1) << 3e)`` at depth d + e.
    """
    c = np.asarray(c, dtype=np.int64).reshape(-1, 3)
    return (_spread(c[:, 0]) << 2) | (_spread(c[:, 1]) << 1) | _spread(c[:, 2])


def demorton(m: np.ndarray) -> np.ndarray:
    """Cells ``(n, 3)`` int64 of Morton keys *m* (inverse of :func:`morton`)."""
    m = np.asarray(m, dtype=np.int64)
    return np.stack([_squeeze(m >> 2), _squeeze(m >> 1), _squeeze(m)], axis=1)


def point_keys(xyz: np.ndarray, origin: np.ndarray, size: float) -> np.ndarray:
    """Morton key of each point's cell at :data:`KEY_DEPTH`; at depth d it is ``>> 3 * (KEY_DEPTH - d)``."""
    return morton(cells(xyz, origin, size, KEY_DEPTH))


def node_keys(xyz: np.ndarray, origin: np.ndarray, size: float, depth: int) -> np.ndarray:
    """Morton key of each point's node at *depth* (the keys of :func:`cloudsieve.store.buckets.bucket`; picklable as a partial)."""
    return morton(cells(xyz, origin, size, depth))


def _first_of_each(keys: np.ndarray, rank: np.ndarray | None = None) -> np.ndarray:
    """Positions (increasing) of the first occurrence of each distinct value of *keys*; with *rank* (same
    length), of the occurrence of lowest rank (the first of equal ranks)."""
    order = np.argsort(keys, kind="stable") if rank is None else np.lexsort((rank, keys))
    sk = keys[order]
    head = np.ones(len(sk), dtype=bool)
    head[1:] = sk[1:] != sk[:-1]
    return np.sort(order[head])


def assign_levels(keys: np.ndarray, *, base_depth: int = 0, leaf_points: int = 50_000,
                  rank: np.ndarray | None = None) -> np.ndarray:
    """The depth (n,) int8 of the node keeping each point (see the module docstring).

    *keys*: :func:`point_keys` of all points of one node at *base_depth*
    (<= :data:`GRID_BITS`, whose ancestors all sample their grids), in order.
    A node holding at most *leaf_points* points is a leaf. *rank* (n,), when
    given: a voxel keeps its point of lowest rank, not its first.
    """
    keys = np.asarray(keys, dtype=np.int64)
    if rank is not None:
        rank = np.asarray(rank)
        if rank.shape != keys.shape:
            raise ValueError(f"rank needs one value per key: {rank.shape} for {keys.shape}")
    level = np.full(len(keys), -1, dtype=np.int8)
    rest = np.arange(len(keys))
    for depth in range(MAX_DEPTH + 1):
        if len(rest) == 0:
            break
        if depth == MAX_DEPTH:
            level[rest] = depth
            break
        if depth >= base_depth:
            # a node at this depth holds the points sharing its cell
            nodes = keys >> (3 * (KEY_DEPTH - depth))
            uniq, counts = np.unique(nodes, return_counts=True)
            small = counts[np.searchsorted(uniq, nodes[rest])] <= leaf_points
            level[rest[small]] = depth
            rest = rest[~small]
            if len(rest) == 0:
                break
        first = _first_of_each(keys[rest] >> (3 * (KEY_DEPTH - depth - GRID_BITS)),  # the voxels
                               None if rank is None else rank[rest])
        level[rest[first]] = depth
        rest = np.delete(rest, first)
    return level


def group_nodes(keys: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points grouped by node, nodes by (depth, Morton key), points in order within a node.

    *keys*: :func:`point_keys`; *level*: :func:`assign_levels`. Returns
    ``order`` (n,) of point positions node after node, and per node (m,)
    ``depths``, ``keys`` (at its depth) and ``counts``, all int64.
    """
    n = len(keys)
    if n == 0:
        e = np.empty(0, dtype=np.int64)
        return e, e, e, e
    level = np.asarray(level, dtype=np.int64)
    key = np.asarray(keys, dtype=np.int64) >> (3 * (KEY_DEPTH - level))
    order = np.lexsort((key, level))  # stable: input order within a node
    sl, sk = level[order], key[order]
    head = np.ones(n, dtype=bool)
    head[1:] = (sl[1:] != sl[:-1]) | (sk[1:] != sk[:-1])
    starts = np.flatnonzero(head)
    return order, sl[starts], sk[starts], np.diff(np.r_[starts, n])
