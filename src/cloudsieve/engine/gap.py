"""The gap bound (``max_gap``) across the cells of the ``eliminate`` rule: the fill and its exact check.

Two passes once every cell's elimination is final (:func:`run_gap`;
docs/architecture.md, "The gap bound"): a **fill** (:func:`fill_task`),
colour by colour, each cell adding its points farther than D from every
kept point it knows (conservative and exact: the kept set only grows), kept
apart in ``simplify/fill_cells`` and joined by the merge; then a **check**
(:func:`gap_task`): with the fill bound at most the halo's margin
(:func:`fill_bound`), the largest distance found is the cloud's, exactly.
"""

from __future__ import annotations

import numpy as np

from ..errors import CloudsieveError
from .cell_work import colour_order, halo_rows

__all__ = ["fill_bound", "fill_task", "gap_task", "run_gap"]


def fill_bound(gap: float, part) -> float:
    """The distance the cells fill to: *gap*, or the halo's margin when the partition has several cells and a
    smaller margin (beyond it a cell does not see its neighbours' points, nor the check)."""
    if part.n_cells > 1 and 0 < part.margin < gap:
        return float(part.margin)
    return float(gap)


def fill_task(where, task, colours: dict) -> dict:
    """A task: one cell's fill, after its lower-colour halo cells' (*colours*: int -> colour of the cell and its
    halo sources). Returns "cell" and "filled"."""
    from ..core.gap import fill_cell

    io = where.open()
    core = io.core(task)
    n = len(core)
    keep = io.keep_at(np.arange(task.region, task.region + n, dtype=np.int64))
    fill = np.zeros(n, dtype=bool)
    if n and not keep.all():
        points, rows, lower = halo_rows(io, task, colours)
        known = io.keep_at(rows) if len(rows) else np.zeros(0, dtype=bool)
        if lower.any():  # their fill is final
            known[lower] |= io.fill_at(rows[lower])
        fill = fill_cell(core, keep, points[known], float(task.params["max_gap"]),
                         bool(task.params.get("keep_duplicates")))
    io.put_fill(task, fill)
    return {"cell": task.cell, "filled": int(fill.sum())}


def gap_task(where, task) -> dict:
    """A task: the largest distance from a point of one cell to the final kept set, once every cell is final.

    Returns "cell", "gap", "filled" (the cell's fill) and "kept" (with it)."""
    from ..core.gap import cell_gap

    io = where.open()
    core = io.core(task)
    own = np.arange(task.region, task.region + len(core), dtype=np.int64)
    fill = io.fill_at(own)
    kept = io.keep_at(own) | fill
    points, rows, _ = halo_rows(io, task)
    known = points[io.keep_at(rows) | io.fill_at(rows)] if len(rows) else np.empty((0, 3))
    # every point is within max_gap once filled: a search bounded just above it finds each nearest kept point
    bound = float(task.params["max_gap"]) * (1 + 1e-9)
    return {"cell": task.cell, "gap": cell_gap(core, np.concatenate([core[kept], known]), bound),
            "filled": int(fill.sum()), "kept": int(kept.sum())}


def run_gap(where, part, regions: np.ndarray, params: dict, runner) -> dict:
    """The gap bound ``params["max_gap"]`` on *where* after :func:`~.cell_scheme.run_cells`: fill, then check.

    Returns ``{"bound": D, "filled": points added, "max": the largest
    distance from a point to the kept set, "fill_to": fill_bound}``.

    Raises
    ------
    CloudsieveError
        A point is farther than D from the kept set (a bug).
    """
    from ..core.colours import apply_order, cell_colours
    from .celltasks import cell_tasks, largest_first

    bound = float(params["max_gap"])
    fill_to = fill_bound(bound, part)
    colours = cell_colours(part.halo_ptr, part.halo_src)
    ordered = apply_order(colours, part.cell_counts, range(part.n_cells))
    tasks = cell_tasks(where, part, regions, ordered, {**params, "max_gap": fill_to}, runner.task_threads, halo=True)
    cols, after = colour_order(tasks, colours)
    runner(fill_task, [(where, t, c) for t, c in zip(tasks, cols)], "cells: fill", after=after)
    tasks = cell_tasks(where, part, regions, largest_first(part, range(part.n_cells)), params, runner.task_threads,
                       halo=True)
    results = runner(gap_task, [(where, t) for t in tasks], "cells: gap")
    found = max((r["gap"] for r in results), default=0.0)
    if found > bound:  # pragma: no cover - the fill's guarantee
        raise CloudsieveError(f"the gap bound was not met: a point lies {found:.6g} from the kept set, above "
                              f"max_gap {bound:g} (a bug: please report it with the input)")
    return {"bound": bound, "filled": int(sum(r["filled"] for r in results)), "max": float(found),
            "fill_to": fill_to}
