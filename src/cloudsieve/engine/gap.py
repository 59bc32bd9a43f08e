"""The gap bound (``max_gap``) across the cells of the ``eliminate`` rule: the fill and its exact check.

**The fill** runs in each cell's elimination task
(:func:`~.cell_scheme.apply_task`, colour by colour), right after the
elimination: :func:`cell_fill` adds the cell's points that lie farther than D
from every kept point the cell knows (:func:`~cloudsieve.core.gap.fill_cell`):
its own kept points and, in its halo, the final points of the lower-colour
cells (their elimination and their fill). Higher-colour cells are not decided
yet and count for nothing: a conservative fill, exact since the kept set only
grows. The elimination itself still sees only the other cells' eliminations,
so the run without the bound keeps a subset of this one's points. The fill
is kept apart (``simplify/fill_cells``, :attr:`~.cell_scheme.ArrayCells.fill`)
and joined to the keep mask by the merge.

**The check** (:func:`run_gap`, a task per cell once every cell is final)
measures each point's distance to the nearest final kept point of its cell
and halo. A kept point outside the halo is farther than the halo's margin, so
with the fill bound at most the margin (:func:`fill_bound`) the largest
distance found is the cloud's, exactly.
"""

from __future__ import annotations

import numpy as np

from ..errors import CloudsieveError

__all__ = ["fill_bound", "cell_fill", "gap_task", "run_gap"]


def fill_bound(gap: float, part) -> float:
    """The distance the cells fill to: *gap*, or the halo's margin when the partition has several cells and a
    smaller margin (beyond it a cell does not see its neighbours' points, nor the check)."""
    if part.n_cells > 1 and 0 < part.margin < gap:
        return float(part.margin)
    return float(gap)


def cell_fill(io, core: np.ndarray, keep: np.ndarray, halo, rows, gap: float, keep_duplicates) -> np.ndarray:
    """The fill (n,) of one cell after its elimination *keep*; *halo*: (points, lower colour, their kept) or None
    (every point kept); *rows*: the lower-colour halo points' rows in the cell-ordered arrays of *io*."""
    from ..core.gap import fill_cell

    n = len(core)
    if halo is None or not n or keep.all():
        return np.zeros(n, dtype=bool)
    points, fixed, known = halo
    known = known.copy()
    if rows is not None:
        known[fixed] |= io.fill_at(rows)
    return fill_cell(core, keep, points[known], float(gap), bool(keep_duplicates))


def gap_task(where, task) -> dict:
    """A task: the largest distance from a point of one cell to the final kept set, once every cell is final.

    Returns "cell", "gap", "filled" (the cell's fill) and "kept" (with it)."""
    from ..core.gap import cell_gap

    io = where.open()
    core = io.core(task)
    n = len(core)
    own = np.arange(task.region, task.region + n, dtype=np.int64)
    fill = io.fill_at(own)
    kept = io.keep_at(own) | fill
    known = np.empty((0, 3))
    if task.halo and n:
        points, cells, pos = io.halo(task)
        if len(points):
            src, start = np.array(sorted(task.halo)), np.array([task.halo[s] for s in sorted(task.halo)])
            rows = start[np.searchsorted(src, cells)] + pos
            known = points[io.keep_at(rows) | io.fill_at(rows)]
    return {"cell": task.cell, "gap": cell_gap(core, np.concatenate([core[kept], known])),
            "filled": int(fill.sum()), "kept": int(kept.sum())}


def run_gap(where, part, regions: np.ndarray, params: dict, runner) -> dict:
    """The check of the gap bound ``params["max_gap"]`` on *where* after :func:`~.cell_scheme.run_cells`.

    Returns ``{"bound": D, "filled": points added, "max": the largest
    distance from a point to the kept set, "fill_to": fill_bound}``.

    Raises
    ------
    CloudsieveError
        A point is farther than D from the kept set (a bug).
    """
    from .celltasks import cell_tasks, largest_first

    bound = float(params["max_gap"])
    tasks = cell_tasks(where, part, regions, largest_first(part, range(part.n_cells)), params, runner.task_threads,
                       halo=True)
    results = runner(gap_task, [(where, t) for t in tasks], "cells: gap")
    found = max((r["gap"] for r in results), default=0.0)
    if found > bound:  # pragma: no cover - the fill's guarantee
        raise CloudsieveError(f"the gap bound was not met: a point lies {found:.6g} from the kept set, above "
                              f"max_gap {bound:g} (a bug: please report it with the input)")
    return {"bound": bound, "filled": int(sum(r["filled"] for r in results)), "max": float(found),
            "fill_to": fill_bound(bound, part)}
