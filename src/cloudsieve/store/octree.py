"""The COPC octree on numpy arrays: cube, node keys, and which node keeps each point.

The root is a cube (:func:`root_cube`); the node ``(d, i, j, k)`` is the cell
``(i, j, k)`` of the cube cut into ``2^d`` along each axis, and a point's cell
at depth *d* is ``floor((xyz - origin) * (2^d / size))``, clipped into the
cube (:func:`cells`). The factors of two depths differ by a power of two, so
the cell at depth d is exactly the cell at depth :data:`KEY_DEPTH` (21)
shifted right: one Morton key per point (:func:`point_keys`) gives its node
and voxel at every depth.

Which node keeps a point (:func:`assign_levels`), top down, with a voxel grid
per node in the manner of Untwine and PDAL's ``writers.copc`` (128 cells
along each axis): a node whose cube holds at most
*leaf_points* points keeps every point that reaches it (a leaf); any other
node lays a grid of ``2^GRID_BITS`` (128) voxels along each axis over its
cube and keeps the first point, in the order given, of each voxel; the rest go
down to its children. A voxel of a node at depth *d* is the node's cell at
depth ``d + GRID_BITS``. A node at :data:`MAX_DEPTH` keeps every point that
reaches it (many copies of one position would otherwise split forever).

The points of a node's subtree, in their order, decide it alone; the voxels
of every node at depth d lie inside one node at depth ``d + GRID_BITS``: so a
task holding the points of one node at depth at most ``GRID_BITS`` finds, for
its points, exactly the levels a build over the whole cloud (in the same
order) would (:func:`cloudsieve.store.copc.export_copc` relies on it).
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRID_BITS", "MAX_DEPTH", "KEY_DEPTH", "root_cube", "cells", "morton", "demorton", "point_keys",
           "node_keys", "assign_levels", "group_nodes"]

#: voxels of a node's sampling grid along each axis: 2^GRID_BITS (Untwine and PDAL use 128)
GRID_BITS = 7
#: deepest node; its voxels (cells at depth MAX_DEPTH + GRID_BITS = 21) pack into 63 bits
MAX_DEPTH = 14
#: depth of the cells whose Morton keys (:func:`point_keys`) give every node and voxel of a point
KEY_DEPTH = MAX_DEPTH + GRID_BITS


def root_cube(bounds: np.ndarray) -> tuple[np.ndarray, float]:
    """The root cube around *bounds*: its lowest corner and its edge.

    Parameters
    ----------
    bounds : ndarray of shape (2, 3), float64
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.

    Returns
    -------
    origin : ndarray of shape (3,), float64
        The lowest corner of *bounds*, as PDAL's ``writers.copc`` puts it (and
        copc-lib, which finds node boxes from the LAS header's minimum, expects).
    size : float
        The largest extent of *bounds* (1.0 for a single position).
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
    """Morton (Z-order) key of cells ``(n, 3)`` (at most 21 bits each): ndarray of shape (n,), int64.

    The descendants at depth ``d + e`` of the cell of key m at depth d are
    the keys ``[m << 3e, (m + 1) << 3e)``.
    """
    c = np.asarray(c, dtype=np.int64).reshape(-1, 3)
    return (_spread(c[:, 0]) << 2) | (_spread(c[:, 1]) << 1) | _spread(c[:, 2])


def demorton(m: np.ndarray) -> np.ndarray:
    """Cells ``(n, 3)`` int64 of Morton keys *m* (inverse of :func:`morton`)."""
    m = np.asarray(m, dtype=np.int64)
    return np.stack([_squeeze(m >> 2), _squeeze(m >> 1), _squeeze(m)], axis=1)


def point_keys(xyz: np.ndarray, origin: np.ndarray, size: float) -> np.ndarray:
    """Morton key of each point's cell at depth :data:`KEY_DEPTH` (21): every coarser cell is a shift of it.

    The cell at depth d of a point is its cell at depth 21 shifted right by
    21 - d bits per axis (exactly: the cells are floors of products by powers
    of two), so its Morton key is ``point_keys >> 3 * (21 - d)``.
    """
    return morton(cells(xyz, origin, size, KEY_DEPTH))


def node_keys(xyz: np.ndarray, origin: np.ndarray, size: float, depth: int) -> np.ndarray:
    """Morton key of each point's node at *depth* (the keys of :func:`cloudsieve.store.buckets.bucket`).

    A module-level function: ``functools.partial(node_keys, origin=..., size=..., depth=...)``
    pickles into tasks.
    """
    return morton(cells(xyz, origin, size, depth))


def _first_of_each(keys: np.ndarray) -> np.ndarray:
    """Positions (increasing) of the first occurrence of each distinct value of *keys*."""
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    head = np.ones(len(sk), dtype=bool)
    head[1:] = sk[1:] != sk[:-1]
    return np.sort(order[head])


def assign_levels(keys: np.ndarray, *, base_depth: int = 0, leaf_points: int = 50_000) -> np.ndarray:
    """The depth of the node that keeps each point (see the module docstring).

    Parameters
    ----------
    keys : ndarray of shape (n,), int64
        :func:`point_keys` of the points of one node at *base_depth* (all of
        them), in their order.
    base_depth : int
        Depth of the node holding the points (at most :data:`GRID_BITS`): its
        ancestors all hold more than *leaf_points* points, so every one of
        them samples its grid.
    leaf_points : int
        A node whose cube holds at most this many points is a leaf.

    Returns
    -------
    ndarray of shape (n,), int8
        The depth of each point's node; the node is the point's cell at that depth.
    """
    keys = np.asarray(keys, dtype=np.int64)
    level = np.full(len(keys), -1, dtype=np.int8)
    rest = np.arange(len(keys))
    for depth in range(MAX_DEPTH + 1):
        if len(rest) == 0:
            break
        if depth == MAX_DEPTH:
            level[rest] = depth
            break
        if depth >= base_depth:
            # a node at this depth holds, in its cube, those of the n points that share its cell
            nodes = keys >> (3 * (KEY_DEPTH - depth))
            uniq, counts = np.unique(nodes, return_counts=True)
            small = counts[np.searchsorted(uniq, nodes[rest])] <= leaf_points
            level[rest[small]] = depth
            rest = rest[~small]
            if len(rest) == 0:
                break
        first = _first_of_each(keys[rest] >> (3 * (KEY_DEPTH - depth - GRID_BITS)))  # the voxels
        level[rest[first]] = depth
        rest = np.delete(rest, first)
    return level


def group_nodes(keys: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points grouped by node: nodes by (depth, Morton key), points in their order within a node.

    Parameters
    ----------
    keys : ndarray of shape (n,), int64
        :func:`point_keys` of the points.
    level : ndarray of shape (n,), int
        :func:`assign_levels` of the points.

    Returns
    -------
    order : ndarray of shape (n,), int64
        Point positions, node after node.
    depths : ndarray of shape (m,), int64
        Depth of each node.
    keys : ndarray of shape (m,), int64
        Morton key of each node at its depth.
    counts : ndarray of shape (m,), int64
        Points of each node (``order`` holds them in runs of these lengths).
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
