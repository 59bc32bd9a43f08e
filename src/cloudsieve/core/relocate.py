"""Relocation of a kept set: restricted Lloyd steps after the elimination (:mod:`.eliminate`).

One step (``RELOCATE_STEPS``) is the default of :func:`cloudsieve.core.eliminate.eliminate`
and of the engine's cells.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidParameterError
from .cellgrid import CellGrid, check_points
from .kernels import eliminate as _ke

__all__ = ["RELOCATE_STEPS", "relocate", "relocate_points", "check_r_max", "numba_threads"]

RELOCATE_STEPS = 1  # restricted Lloyd steps in eliminate() (more changed nothing measurable)


def check_r_max(r_max) -> float:
    """r_max as a float, or InvalidParameterError."""
    if not (isinstance(r_max, (int, float, np.integer, np.floating)) and r_max > 0):
        raise InvalidParameterError(f"r_max must be a positive number (inf: keep all), got {r_max!r}")
    return float(r_max)


class numba_threads:
    """numba's thread count set to ``threads`` inside the block (None: unchanged)."""

    def __init__(self, threads):
        self.threads = threads

    def __enter__(self):
        # None touches nothing: querying numba's thread count starts its threading layer, and after
        # GNU OpenMP's a process cannot fork
        if self.threads is not None:
            import numba

            self.old = numba.get_num_threads()
            numba.set_num_threads(max(1, min(int(self.threads), numba.config.NUMBA_NUM_THREADS)))

    def __exit__(self, *exc):
        if self.threads is not None:
            import numba

            numba.set_num_threads(self.old)


def relocate(points, keep, r_max, *, halo=None, halo_keep=None, iterations: int = RELOCATE_STEPS,
             threads: int | None = None) -> np.ndarray:
    """Restricted Lloyd steps on a kept set: lower squared error, same count.

    Each kept point moves to the point of its Voronoi region nearest the region's
    centroid, unless a point of the region would end farther than both the region's
    current farthest and r_max (the search reaches 2 r_max). Kept halo points
    (``halo_keep``, default none) pull but do not move. Stops after ``iterations``
    steps or when nothing moves.

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    keep : array_like of shape (n,), bool
    r_max : float
    halo : array_like of shape (h, 3), optional
    halo_keep : array_like of shape (h,), bool, optional
    iterations : int
    threads : int, optional

    Returns
    -------
    ndarray of shape (n,), bool
    """
    pts = check_points(points)
    n = len(pts)
    kp = np.asarray(keep)
    if kp.shape != (n,) or kp.dtype != bool:
        raise InvalidParameterError(f"keep must be a bool mask of shape ({n},), got {kp.dtype} {kp.shape}")
    hal = np.zeros((0, 3)) if halo is None else check_points(halo, "halo")
    hk = np.zeros(len(hal), dtype=bool) if halo_keep is None else np.asarray(halo_keep)
    if hk.shape != (len(hal),) or hk.dtype != bool:
        raise InvalidParameterError(f"halo_keep must be a bool mask of shape ({len(hal)},), got {hk.dtype} {hk.shape}")
    r_max = check_r_max(r_max)
    if int(iterations) != iterations or iterations < 0:
        raise InvalidParameterError(f"iterations must be an integer >= 0, got {iterations!r}")
    if n == 0 or not kp.any() or not math.isfinite(r_max) or iterations == 0:
        return kp.copy()
    with numba_threads(threads):
        return relocate_points(pts, kp, hal, hk, r_max, int(iterations))


def relocate_points(pts, kp, hal, hk, r_max, iterations, grid=None, near=None) -> np.ndarray:
    """:func:`relocate` on valid arrays (no checks).

    ``grid``: a :class:`.cellgrid.CellGrid` of ``[pts, hal]`` with side 2 r_max, or None
    to build one; ``near``: per grid row its nearest kept point
    (:func:`.kernels.grid.nearest_kept`), -1 where unknown.
    """
    if grid is None:  # else the grid the elimination built on the same points and cell side
        grid = CellGrid(np.concatenate([pts, hal]) if len(hal) else pts, 2.0 * r_max)
    return relocate_on_grid(len(pts), kp, hk, r_max, iterations, grid, near)


def relocate_on_grid(n, kp, hk, r_max, iterations, grid, near=None) -> np.ndarray:
    """:func:`relocate_points` on the grid of the n points and the halo (which holds the points)."""
    src = grid.order
    kept = np.concatenate([kp, hk])[src].astype(np.uint8)
    movable = (src < n).astype(np.uint8)
    movable[grid.copy] = 0
    for step in range(iterations):
        if step == 0 and near is not None:
            near = near.copy()
            rows = np.flatnonzero(near < 0)
            near[rows] = grid.nearest_kept(kept, rows)
        else:
            near = grid.nearest_kept(kept, np.arange(len(src)))
        new = _ke.relocate(grid.P, near, kept, movable, src, r_max * r_max)
        if np.array_equal(new, kept):
            break
        kept = new
    out = np.empty(len(src), dtype=bool)
    out[src] = kept.astype(bool)
    return out[:n]
