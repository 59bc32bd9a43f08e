"""The eliminate rule's cells stage, one driver for every run (:func:`run_cells`): weighted sample
elimination across cells, exact count.

The store's run (:mod:`.eliminate`: :class:`~.eliminate.StoreCells`, a task a cell on the run's runner,
resumable), a small input in memory (:mod:`.small`) and the in-memory API (``simplify_points`` with the rule
``eliminate``: :func:`eliminate_points`) run the same functions on the same cells (:func:`partition` in memory
as the store's :func:`~.partition.build_partition`), on a store or on arrays (:class:`ArrayCells`, its tasks
mapped by :class:`ThreadMap`: a cell's points in input order, in its region of the keep mask, as the store
holds them), so a cloud's kept set does not depend on where it runs (tests/test_engine_small.py). The
in-memory rule (:mod:`cloudsieve.core.eliminate`) run cell by cell:

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
   (:func:`cell_counts`, :func:`~cloudsieve.core.packing.kept_counts`: proportional, clipped to each cell's distinct
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
import os
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from ..chunk import take_rows
from ..core.kernels.scatter import group_rows
from .halo import band_halo, band_mask

__all__ = ["partition", "ArrayCells", "ThreadMap", "eliminate_cells", "eliminate_points", "share_task", "apply_task",
           "run_cells", "cell_share", "cell_counts", "cell_keep"]


def partition(xyz: np.ndarray, origin: np.ndarray, opts: dict, target: int) -> tuple:
    """:func:`~.partition.build_partition` of the eliminate rule (a halo, r_max for *target*) on *xyz*: the
    :class:`~.partition.Partition` (no store, no runs) and the rows of each cell's points in input order, cell
    after cell."""
    from ..core import neighbour_count
    from .partition import Partition, fit_sample, halo_lists
    from .sample import n_cells_for, plan_sample

    n = len(xyz)
    p = n_cells_for(n, opts["cell_size"])
    seed = opts["seed"]
    sample = xyz[plan_sample(n, p, seed)]
    k = int(neighbour_count(opts["cluster_size"], opts["k0"], opts["k_min"]))
    centers, (_, _, margin), r_max = fit_sample(sample, n, p, seed, origin, k, int(target))
    labels, pairs = np.zeros(n, dtype=np.int64), np.empty((0, 2), dtype=np.int64)
    if p > 1:  # as the label tasks (each point's label is its own: the store's chunks do not matter)
        from .label import label_points

        labels, pairs = label_points(centers, xyz, margin, threads=os.cpu_count() or 1)
    order, bounds = group_rows(labels, p, os.cpu_count() or 1)  # on the cores (numpy's stable sort: one)
    return Partition(centers, np.diff(bounds), *halo_lists(pairs, p), margin, 0, 0, 0, r_max), order


class ArrayCells:
    """The stage's store in memory (:func:`run_cells`): the points *xyz* of the partition *part*, its cells'
    rows *order* (:func:`partition`), each cell's share and band, the keep mask in cell order (a cell's region
    as in the work store)."""

    path = ""  # no store to open

    def __init__(self, xyz: np.ndarray, part, order: np.ndarray) -> None:
        self.xyz, self.part, self.order = xyz, part, order
        self.regions = np.cumsum(part.cell_counts) - part.cell_counts
        p = part.n_cells
        self.share, self.bands = [None] * p, [None] * p
        self.keep = np.zeros(len(xyz), dtype=bool)
        self.markers = np.zeros(p, dtype=bool), np.zeros(p, dtype=bool)  # done, scored: none

    def open(self) -> "ArrayCells":
        return self

    def core(self, task) -> np.ndarray:
        return take_rows(self.xyz, self.order[task.region : task.region + self.part.cell_counts[task.cell]])

    def put_share(self, task, core, sizes, distinct, band) -> None:
        self.share[task.cell] = np.r_[float(distinct), sizes]
        self.bands[task.cell] = core[band], band

    def shares(self) -> np.ndarray:
        return np.array(self.share)

    def halo(self, task) -> tuple:
        return band_halo(((s, *self.bands[s]) for s in sorted(task.halo) if len(self.bands[s][1])), task.centers,
                         task.cell, task.margin)

    def keep_at(self, rows: np.ndarray) -> np.ndarray:
        return self.keep[rows]

    def put_keep(self, task, keep: np.ndarray) -> None:
        self.keep[task.region : task.region + len(keep)] = keep

    def input_keep(self) -> np.ndarray:
        """The keep mask in input order."""
        keep = np.empty_like(self.keep)
        keep[self.order] = self.keep
        return keep


class ThreadMap:
    """The runner of :func:`run_cells` in memory: the shares on threads, the cells' eliminations in turn (the
    order given runs each after the cells it reads), each task on every core."""

    task_threads = os.cpu_count() or 1

    def __call__(self, func, args, stage: str, after=None) -> list:
        if after is not None:
            return [func(*a) for a in args]
        with ThreadPoolExecutor(self.task_threads) as pool:
            return list(pool.map(lambda a: func(*a), args))


def eliminate_cells(xyz: np.ndarray, part, order: np.ndarray, target: int,
                    keep_duplicates: bool) -> tuple[np.ndarray, int]:
    """The keep mask (input order) and the distinct points of :func:`run_cells` on *xyz* in memory (the
    partition *part* and its rows *order*: :func:`partition`)."""
    where = ArrayCells(xyz, part, order)
    *_, distinct = run_cells(where, part, where.regions, {"keep_duplicates": keep_duplicates}, ThreadMap(),
                             int(target))
    return where.input_keep(), distinct


def eliminate_points(xyz: np.ndarray, target: int, *, seed: int, cluster_size: int, k0: float, k_min: int,
                     keep_duplicates: bool) -> np.ndarray:
    """The keep mask (n,) of the cloud *xyz* (n, 3) float64 reduced to *target* points as a run of the engine
    keeps it with these options and the default ``cell_size``: :func:`partition`, then :func:`eliminate_cells`
    (the in-memory API's rule ``eliminate``)."""
    from ..chunk import xyz_bounds
    from ..params import COMMANDS

    opts = {"cell_size": COMMANDS["simplify"]["cell_size"].default, "seed": seed, "cluster_size": cluster_size,
            "k0": k0, "k_min": k_min}
    part, order = partition(xyz, np.asarray(xyz_bounds(xyz)[0], dtype=np.float64), opts, int(target))
    return eliminate_cells(xyz, part, order, int(target), keep_duplicates)[0]


# ---------------------------------------------------------------- the stage


def _threads(task) -> int:
    return int(task.params.get("threads") or 1)


def share_task(where, task, dependents: dict) -> dict[str, Any]:
    """One cell's share (:func:`cell_share`) from the points of *where* (a store or :class:`ArrayCells`),
    stored there (a task): its packing sizes, distinct points and band (its points in the halo of a cell of
    *dependents*: int -> centre). ``task.params["r_max"]`` is the global radius (inf: no packing).

    The halo is not read: it is most of a cell's reading (whole neighbouring cells, filtered), and the shares
    only split an exact total. Without it the packings along the border (a band of about r_max, 1-2% of a
    100,000-point cell) miss their outside neighbours and hold a few more points, which raises every cell's
    size by a similar fraction. Returns "cell", "n", "band", "seconds" (small)."""
    t0 = time.perf_counter()
    io = where.open()
    core = io.core(task)
    sizes, distinct, band = cell_share(core, float(task.params["r_max"]), task.centers, task.cell, dependents,
                                       task.margin, _threads(task), ladder=task.params["ladder"])
    io.put_share(task, core, sizes, distinct, band)
    return {"cell": task.cell, "n": len(core), "band": len(band), "seconds": time.perf_counter() - t0}


def apply_task(where, task, count: int, colours: dict) -> dict[str, Any]:
    """The elimination of one cell of *where* to *count* of its points (:func:`cell_keep`), its keep mask
    stored there (a task): the lower colours' final decisions (*colours*: int -> colour of the cell and of its
    halo sources, the lower ones done) are its fixed (kept) and gone (removed) points, the higher colours'
    points its halo, eliminated along but not counted. Returns "cell", "n", "kept", "seconds" (small)."""
    t0 = time.perf_counter()
    io = where.open()
    core = io.core(task)
    n, halo = len(core), None
    if 0 < count < n:  # else no elimination: no halo
        points, cells, pos = io.halo(task)
        earlier = [s for s in task.halo if colours[s] < colours[task.cell]]
        fixed = np.isin(cells, earlier)
        halo_keep = np.zeros(len(points), dtype=bool)
        if fixed.any():  # their final decisions, at their regions' positions
            src, start = np.array(sorted(task.halo)), np.array([task.halo[s] for s in sorted(task.halo)])
            halo_keep[fixed] = io.keep_at(start[np.searchsorted(src, cells[fixed])] + pos[fixed])
        halo = points, fixed, halo_keep
    keep = cell_keep(core, count, float(task.params["r_max"]), halo, _threads(task), task.params.get("staged"),
                     task.params.get("keep_duplicates"))
    io.put_keep(task, keep)
    return {"cell": task.cell, "n": n, "kept": int(keep.sum()), "seconds": time.perf_counter() - t0}


def run_cells(where, part, regions: np.ndarray, params: dict, runner, target: int) -> tuple[int, int, int, int]:
    """The cells stage of the eliminate rule on *where* (the work store, or :class:`ArrayCells`): the shares,
    the counts, the elimination of each cell colour by colour; only the cells not marked (resume).

    Parameters
    ----------
    where
        ``markers`` (done, scored: (P,) bool), ``shares()``, and ``open()``: the reads and writes of a task.
    part : Partition
        Built for this target (``part.r_max`` set).
    regions : ndarray of shape (P,), int64
    params : dict
        The run's parameters.
    runner
        ``runner(func, args, stage, after=None)``: the results in the order of *args*; ``after[i]``: the
        calls call i waits for. ``runner.task_threads``: each task's threads.
    target : int
        Points kept in all.

    Returns
    -------
    (computed, reused, points, distinct) : cells applied now, cells found done, points whose share was
        computed now, distinct points of the cloud
    """
    from ..core.colours import apply_order, cell_colours, readers
    from .celltasks import cell_tasks, largest_first

    r_max = math.inf if part.r_max is None else float(part.r_max)
    params = {**params, "r_max": r_max, "ladder": part.n_cells > 1}  # one cell's count is the target
    done, scored = where.markers
    todo = largest_first(part, [j for j in range(part.n_cells) if not scored[j]])
    tasks = cell_tasks(where, part, regions, todo, params, runner.task_threads, halo=False)
    deps = readers(part.halo_ptr, part.halo_src)  # the cells that read each cell's band
    args = [(where, t, {int(i): part.centers[i] for i in deps[t.cell]}) for t in tasks]
    results = runner(share_task, args, "cells: share")
    share = where.shares()
    distinct = share[:, 0].astype(np.int64)
    q, params["staged"] = cell_counts(share[:, 1:], distinct, target, r_max)
    colours = cell_colours(part.halo_ptr, part.halo_src)
    # a cell starts once the cells of lower colours in its halo are done (it reads their results), not once the
    # whole lower colours are
    ordered = apply_order(colours, part.cell_counts, [j for j in range(part.n_cells) if not done[j]])
    tasks = cell_tasks(where, part, regions, ordered, params, runner.task_threads, halo=True)
    at = {t.cell: i for i, t in enumerate(tasks)}
    args = [(where, t, int(q[t.cell]), {int(s): int(colours[s]) for s in (t.cell, *t.halo)}) for t in tasks]
    after = [sorted(at[s] for s in t.halo if s in at and colours[s] < colours[t.cell]) for t in tasks]
    runner(apply_task, args, "cells: apply", after=after)
    return len(ordered), int(done.sum()), int(sum(r["n"] for r in results)), int(distinct.sum())


# ---------------------------------------------------------------- a cell's work (the store's tasks call them too)


def cell_share(core: np.ndarray, r_max: float, centers, cell: int, dependents: dict, margin: float,
               threads: int | None = None, ladder: bool = True) -> tuple[np.ndarray, int, np.ndarray]:
    """The packing sizes (L,) of the points *core* (n, 3) of *cell* along
    :data:`~cloudsieve.core.packing.LADDER` x *r_max* (zeros when r_max is infinite or not *ladder*: one
    cell's count is the target), its distinct points, and its band: the positions of its points in the halo of
    a cell of *dependents* (int -> centre; *centers* [cell] its own centre), on *threads* numba threads."""
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
    """Each cell's kept count q (P,), summing to *target*, from the cells' packing sizes (P, L) and distinct
    points (P,) (:func:`~cloudsieve.core.packing.kept_counts`), and whether every cell runs in stages
    (:func:`~cloudsieve.core.staged.small_share`: one decision for the run)."""
    from ..core.packing import kept_counts, ladder_shares
    from ..core.staged import small_share

    expected = ladder_shares(sizes, int(target)) if math.isfinite(r_max) else distinct
    return kept_counts(expected, distinct, int(target)), small_share(int(target), int(distinct.sum()))


def cell_keep(core: np.ndarray, count: int, r_max: float, halo: tuple, threads: int | None, staged,
              keep_duplicates) -> np.ndarray:
    """The keep mask (n,) of a cell's points *core* (n, 3): the elimination to *count* of them
    (:func:`~cloudsieve.core.eliminate_cells.eliminate_cell`) with *halo* = (points (h, 3), which are the
    lower colours' final decisions (h,), which of those are kept (h,)); every copy of a kept point with
    *keep_duplicates*."""
    from ..core.eliminate import CELL_POINTS
    from ..core.eliminate_cells import eliminate_cell

    n = len(core)
    keep = np.full(n, count >= n)
    if 0 < count < n:
        points, fixed, halo_keep = halo
        keep = eliminate_cell(core, int(count), r_max, halo=points, decided=fixed, halo_keep=halo_keep,
                              threads=threads, cell_points=CELL_POINTS, staged=staged)
    if keep_duplicates and n:  # every copy of a kept point too
        from ..core.duplicates import first_copies

        keep = keep[first_copies(core)]
    return keep
