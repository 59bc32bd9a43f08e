"""One cell's work in the ``eliminate`` cells stage (:mod:`.cell_scheme`, :mod:`.class_cells`): its share
(:func:`cell_share`), the counts of all cells (:func:`cell_counts`), its elimination (:func:`cell_keep`)."""

from __future__ import annotations

import math

import numpy as np

from .halo import band_mask

__all__ = ["task_threads", "halo_rows", "colour_order", "cell_share", "cell_counts", "cell_keep"]


def task_threads(task) -> int:
    """A cell task's threads (``params["threads"]``, default 1); results do not depend on it."""
    return int(task.params.get("threads") or 1)


def halo_rows(io, task, colours: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cell's halo: points (h, 3), their rows in *io*'s cell-ordered arrays, and which come from cells of a
    lower colour (*colours*: int -> colour of the cell and its sources; their decisions are final)."""
    if not task.halo:
        return np.empty((0, 3)), np.empty(0, np.int64), np.zeros(0, dtype=bool)
    points, cells, pos = io.halo(task)
    src = np.array(sorted(task.halo), dtype=np.int64)
    start = np.array([task.halo[s] for s in sorted(task.halo)], dtype=np.int64)
    rows = start[np.searchsorted(src, cells)] + pos if len(cells) else np.zeros(0, dtype=np.int64)
    lower = [s for s in task.halo if colours[s] < colours[task.cell]] if colours else []
    return points, rows, np.isin(cells, lower)


def colour_order(tasks: list, colours: np.ndarray) -> tuple[list, list]:
    """Each task's colours (int -> colour of its cell and halo sources) and the tasks it waits for (``after``):
    those of the lower-colour cells of its halo."""
    at = {t.cell: i for i, t in enumerate(tasks)}
    after = [sorted(at[s] for s in t.halo if s in at and colours[s] < colours[t.cell]) for t in tasks]
    return [{int(s): int(colours[s]) for s in (t.cell, *t.halo)} for t in tasks], after


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
