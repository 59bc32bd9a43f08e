"""One cell's work in the ``eliminate`` cells stage (:mod:`.cell_scheme`, :mod:`.class_cells`): its share
(:func:`cell_share`), the counts of all cells (:func:`cell_counts`), its elimination (:func:`cell_keep`)."""

from __future__ import annotations

import math

import numpy as np

from .halo import band_mask

__all__ = ["task_threads", "cell_share", "cell_counts", "cell_keep"]


def task_threads(task) -> int:
    """A cell task's threads (``params["threads"]``, default 1); results do not depend on it."""
    return int(task.params.get("threads") or 1)


def cell_share(core: np.ndarray, r_max: float, centers, cell: int, dependents: dict, margin: float,
               threads: int | None = None, ladder: bool = True) -> tuple[np.ndarray, int, np.ndarray]:
    """Packing sizes (L,) of *core* (n, 3) along LADDER x *r_max*, its distinct points, and its band.

    Sizes are zeros when r_max is infinite or not *ladder*. The band: rows of
    *core* in the halo of a cell of *dependents* (int -> centre)."""
    from ..core.duplicates import copy_rows
    from ..core.packing import LADDER, packing_ladder
    from ..core.relocate import numba_threads

    n = len(core)
    if n and math.isfinite(r_max) and ladder:
        with numba_threads(threads):  # the task's share of the cores
            sizes, distinct = packing_ladder(core, r_max)
    else:
        sizes, distinct = np.zeros(len(LADDER)), int(n - copy_rows(core).sum()) if n else 0
    band = np.flatnonzero(band_mask(core, {**dependents, cell: centers[cell]}, cell, dependents, margin))
    return sizes, int(distinct), band


def cell_counts(sizes: np.ndarray, distinct: np.ndarray, target: int, r_max: float) -> tuple[np.ndarray, bool]:
    """Each cell's kept count q (P,), summing to *target*, and whether every cell runs in stages."""
    from ..core.packing import kept_counts, ladder_shares
    from ..core.staged import small_share

    expected = ladder_shares(sizes, int(target)) if math.isfinite(r_max) else distinct
    return kept_counts(expected, distinct, int(target)), small_share(int(target), int(distinct.sum()))


def cell_keep(core: np.ndarray, count: int, r_max: float, halo: tuple, threads: int | None, staged,
              keep_duplicates) -> np.ndarray:
    """The keep mask (n,) of *core* eliminated to *count* points (:func:`~cloudsieve.core.eliminate_cells.eliminate_cell`).

    *halo*: (points (h, 3), decided (h,), kept (h,)); *keep_duplicates* keeps every copy of a kept point."""
    from ..core.eliminate import CELL_POINTS
    from ..core.eliminate_cells import eliminate_cell

    n = len(core)
    keep = np.full(n, count >= n)
    if 0 < count < n:
        points, fixed, halo_keep = halo
        keep = eliminate_cell(core, int(count), r_max, halo=points, decided=fixed, halo_keep=halo_keep,
                              threads=threads, cell_points=CELL_POINTS, staged=staged)
    if keep_duplicates and n:
        from ..core.duplicates import first_copies

        keep = keep[first_copies(core)]
    return keep
