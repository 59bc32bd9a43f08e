"""The cells stage of the ``eliminate`` rule: weighted sample elimination across cells, exact count.

The in-memory rule (:mod:`cloudsieve.core.eliminate`) run out of core, cell
by cell:

1. **r_max** -- one global elimination radius, solved before the cells on
   the partition's uniform sample (:func:`cloudsieve.core.radius.global_radius`, called by
   :func:`cloudsieve.engine.partition.build_partition`, recorded in the
   partition's attributes, so a resumed run uses the same one); the halo
   margin is at least 2.2 r_max (the elimination and the relocation reach
   2 r_max).
2. **the shares** (:func:`share_task`, one small task per cell): the sizes
   of greedy packings of the cell's points at radii
   :data:`~cloudsieve.core.packing.LADDER` x r_max
   (:func:`~cloudsieve.core.packing.packing_ladder`: a cheap rehearsal of the
   elimination, which the k-NN area model was not: module
   :mod:`cloudsieve.core.packing`; the halo is not read); stored with the
   cell's distinct point count in ``simplify/share`` (P, 1 + L), with the
   cell's band (its points in the halos of the cells that list it,
   :func:`~cloudsieve.engine.halo.band_mask`) in ``simplify/band_*``, then
   ``simplify/scored[cell]``. The driver takes each cell's packing size at
   the radius where they total the target
   (:func:`~cloudsieve.core.packing.ladder_shares`) and turns
   them into integer counts q_j summing exactly to the target
   (:func:`~cloudsieve.core.packing.kept_counts`: proportional, clipped to each cell's distinct
   points, largest remainder, ties by cell id; exact copies only when the
   distinct points do not suffice).
3. **the elimination** (:func:`apply_task`), colour by colour
   (:func:`~cloudsieve.core.colours.cell_colours`: cells that share a
   halo never share a colour; one runner call, in which each cell waits only
   for the cells of lower colours in its halo): each cell reads its halo
   from its sources' bands
   (:func:`~cloudsieve.engine.halo.read_band_halo`: the same points as
   from the whole cells) and runs
   :func:`~cloudsieve.core.eliminate_cells.eliminate_cell`: the elimination
   (:mod:`cloudsieve.core.eliminate`) stopped at q_j of its own points, with the FINAL decisions of its lower-colour
   neighbours (their kept points fixed: they weigh, never go; their removed
   points gone: represented by their nearest point, so the coverage term
   sees the area they leave) and the points of its higher-colour neighbours
   as halo (eliminated along, not counted), and keeps its q_j points left.
   Without the lower colours' decisions both sides of a border remove their
   border points, each expecting the other's to stay: holes at the borders
   (autzen_trim at 50% in 14 cells). Then one restricted Lloyd step,
   :func:`~cloudsieve.core.relocate.relocate`, with the final masks of the
   lower colours as the halo's kept points (for the higher colours, which
   have not decided, the points this elimination left), on the same grid.
   The count does not change. Writes
   ``simplify/keep_cells``, then ``simplify/done[cell]``. A run keeping
   less than 1 in :data:`~cloudsieve.core.staged.STAGED_BELOW` of its
   distinct points runs every cell's elimination in stages of about half
   (:mod:`cloudsieve.core.staged`: a cell's lists and cells as at 50%
   kept).
   Above :data:`~cloudsieve.core.eliminate.CELL_POINTS` points the cell is
   eliminated over k-d cells, as the in-memory rule is, its halo around them:
   one elimination over the whole cell waits on memory, its arrays beyond
   the caches (the D1/D2 PSNR of the shared scans within 0.12 dB of it,
   point max up to 5% higher; docs/architecture.md).

A crash anywhere resumes from the markers: cells with a share are not read
again, the counts are recomputed from the stored shares (the same), and
only the cells not done are applied, colour by colour (the colours are a
pure function of the partition; a cell reads only lower colours' results,
and starts after the cells it reads are done).

No clusters are needed (the entropy and geometric terms are off): ``method``
and ``cluster_size`` are unused by this rule, and so is ``halo_context``
(the rule always reads the halo).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from .cells import CellTask, cell_tasks, largest_first
from ..core.colours import cell_colours
from ..core.packing import kept_counts, ladder_shares
from ..core.staged import small_share
from .halo import band_mask, read_band_halo
from ..store.streaming import gathered
from .runs import cell_runs, read_cell, write_slices

__all__ = ["share_task", "apply_task", "run_eliminate"]


# ---------------------------------------------------------------- the tasks


def _threads(task: CellTask) -> int:
    return int(task.params.get("threads") or 1)


def _read(task: CellTask):
    """The store's group, the cell's points (n, 3) and its halo: points (h, 3), their cells and positions
    (from the bands the count pass stored)."""
    from ..store import PointStore

    g = PointStore.open(task.store_path, "r+").group
    core = read_cell(g, cell_runs(g, task.cell))
    return g, core, read_band_halo(g, task.halo, task.centers, task.cell, task.margin)


def share_task(task: CellTask, dependents: dict) -> dict[str, Any]:
    """The packing sizes of one cell, its distinct points, and its band (a task).

    Writes ``simplify/share[cell]`` = (distinct, sizes of the greedy packings
    of the cell's points at radii :data:`~cloudsieve.core.packing.LADDER` x
    r_max), then ``simplify/scored[cell]``. ``task.params["r_max"]`` is the
    global radius (inf: no packing, every point kept). Also stores the cell's
    band (:func:`~cloudsieve.engine.halo.band_mask`: its points in the halo
    of a cell of *dependents*) in ``simplify/band_*``, which the elimination
    reads instead of whole neighbouring cells.

    The halo is not read: it is most of a cell task's reading (whole
    neighbouring cells, filtered), and the shares only split an exact total.
    Without it the packings along the border (a band of about r_max, 1-2% of
    a 100,000-point cell) miss their outside neighbours and hold a few more
    points, which raises every cell's size by a similar fraction.

    Parameters
    ----------
    task : CellTask
    dependents : dict int -> ndarray of shape (3,)
        The cells that list this one among their halo sources, and their centres.

    Returns
    -------
    dict with "cell", "n", "band", "seconds" (small).
    """
    from ..core.duplicates import copy_rows
    from ..core.packing import LADDER, packing_ladder
    from ..core.relocate import numba_threads
    from ..store import PointStore

    t0 = time.perf_counter()
    g = PointStore.open(task.store_path, "r+").group
    core = read_cell(g, cell_runs(g, task.cell))  # the store's points: finite float64 (checked at ingest)
    n = len(core)
    r_max = float(task.params["r_max"])
    if n and math.isfinite(r_max):
        with numba_threads(_threads(task)):  # the task's share of the cores
            sizes, distinct = packing_ladder(core, r_max)
    else:
        sizes, distinct = np.zeros(len(LADDER)), int(n - copy_rows(core).sum()) if n else 0
    band = np.flatnonzero(band_mask(core, {**dependents, task.cell: task.centers[task.cell]}, task.cell, dependents,
                                    task.margin))
    bands = [("simplify/band_xyz", task.region, core[band]),
             ("simplify/band_pos", task.region, band.astype(np.int64))] if len(band) else []
    write_slices(g, [*bands, ("simplify/band_count", task.cell, np.array([len(band)], dtype=np.int64)),
                      ("simplify/duplicates", task.cell, np.array([n - distinct], dtype=np.int64)),
                      ("simplify/share", task.cell, np.r_[float(distinct), sizes][None, :])])
    g["simplify/scored"][task.cell : task.cell + 1] = np.ones(1, dtype=np.uint8)  # after them: the marker
    return {"cell": task.cell, "n": n, "band": len(band), "seconds": time.perf_counter() - t0}


def _final_keep(g, task: CellTask, cells: np.ndarray, pos: np.ndarray, sources) -> np.ndarray:
    """The final keep decisions (``simplify/keep_cells``) of the halo points of cells *sources*."""
    kc = g["simplify/keep_cells"].async_array
    keep = np.zeros(len(cells), dtype=bool)
    sels = [(s, np.flatnonzero(cells == s)) for s in sources]
    sels = [(s, sel) for s, sel in sels if len(sel)]
    # every source in one call of zarr's event loop
    for (s, sel), got in zip(sels, gathered(kc.get_orthogonal_selection((task.halo[s] + pos[sel],))
                                            for s, sel in sels)):
        keep[sel] = np.asarray(got)
    return keep


def apply_task(task: CellTask, count: int, colours: dict) -> dict[str, Any]:
    """The elimination of one cell stopped at *count* of its points, one relocation, its keep mask (a task).

    The lower colours' final decisions are the cell's fixed (kept) and gone
    (removed) points; the higher colours' points its halo, eliminated along
    but not counted (module docstring).

    Parameters
    ----------
    task : CellTask
    count : int
        q_j of :func:`~cloudsieve.core.packing.kept_counts`, in [0, n].
    colours : dict int -> int
        Colour (:func:`~cloudsieve.core.colours.cell_colours`) of the cell
        and of each of its halo sources; cells of lower colours must be done.

    Returns
    -------
    dict with "cell", "n", "kept", "seconds" (small).
    """
    from ..core.eliminate import CELL_POINTS
    from ..core.eliminate_cells import eliminate_cell

    t0 = time.perf_counter()
    r_max = float(task.params["r_max"])
    g, core, (halo, cells, pos) = _read(task)
    n = len(core)
    keep = np.full(n, count >= n)
    if 0 < count < n:
        earlier = [s for s in task.halo if colours[s] < colours[task.cell]]
        fixed = np.isin(cells, earlier)
        halo_keep = np.zeros(len(halo), dtype=bool)
        if earlier:
            halo_keep[fixed] = _final_keep(g, task, cells, pos, earlier)[fixed]
        keep = eliminate_cell(core, int(count), r_max, halo=halo, decided=fixed, halo_keep=halo_keep,
                              threads=_threads(task), cell_points=CELL_POINTS, staged=task.params.get("staged"))
    if task.params.get("keep_duplicates") and n:  # every copy of a kept point too
        from ..core.duplicates import first_copies

        keep = keep[first_copies(core)]
    g["simplify/keep_cells"][task.region : task.region + n] = keep
    g["simplify/done"][task.cell : task.cell + 1] = np.ones(1, dtype=np.uint8)
    return {"cell": task.cell, "n": n, "kept": int(keep.sum()), "seconds": time.perf_counter() - t0}


# ---------------------------------------------------------------- the stage


def run_eliminate(store, part, regions: np.ndarray, params: dict, runner, target: int) -> tuple[int, int, int, None]:
    """The cells stage of the eliminate rule: the shares, the counts, the elimination of each cell (resumable).

    Parameters
    ----------
    store : PointStore
    part : Partition
        Built for this target (``part.r_max`` set).
    regions : ndarray of shape (P,), int64
    params : dict
        The run's recorded parameters.
    runner : Runner
    target : int
        Points kept in all.

    Returns
    -------
    (computed, reused, points, None) : cells applied now, cells found done, points whose share was
        computed now, and no threshold (the rule has none)
    """
    r_max = math.inf if part.r_max is None else float(part.r_max)
    params = {**params, "r_max": r_max}
    done = np.asarray(store.group["simplify/done"][:]).astype(bool)
    scored = np.asarray(store.group["simplify/scored"][:]).astype(bool)
    todo = largest_first(part, [j for j in range(part.n_cells) if not scored[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads, halo=False)
    # the transpose of the halo lists: the cells that read each cell's band
    owner = np.repeat(np.arange(part.n_cells), np.diff(part.halo_ptr))
    order = np.lexsort((owner, part.halo_src))
    ptr = np.r_[0, np.cumsum(np.bincount(part.halo_src, minlength=part.n_cells))]
    readers = owner[order]
    args = [(t, {int(i): part.centers[i] for i in readers[ptr[t.cell] : ptr[t.cell + 1]]}) for t in tasks]
    results = runner(share_task, args, "cells: share")
    share = np.asarray(store.group["simplify/share"][:])
    distinct = share[:, 0].astype(np.int64)
    expected = ladder_shares(share[:, 1:], int(target)) if math.isfinite(r_max) else distinct
    q = kept_counts(expected, distinct, int(target))
    params["staged"] = small_share(int(target), int(distinct.sum()))  # one decision for every cell of the run
    todo = [j for j in range(part.n_cells) if not done[j]]
    colours = cell_colours(part.halo_ptr, part.halo_src)
    # colour by colour, largest first; a cell starts once the cells of lower colours in its halo are done (it
    # reads their results), not once the whole lower colours are
    ordered = [j for c in range(int(colours.max()) + 1 if len(colours) else 0)
               for j in largest_first(part, [j for j in todo if colours[j] == c])]
    tasks = cell_tasks(store, part, regions, ordered, params, runner.task_threads, halo=True)
    at = {t.cell: i for i, t in enumerate(tasks)}
    args = [(t, int(q[t.cell]), {int(s): int(colours[s]) for s in (t.cell, *t.halo)}) for t in tasks]
    after = [sorted(at[s] for s in t.halo if s in at and colours[s] < colours[t.cell]) for t in tasks]
    runner(apply_task, args, "cells: apply", after=after)
    return len(todo), int(done.sum()), int(sum(r["n"] for r in results)), None
