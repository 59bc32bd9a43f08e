"""The eliminate rule's cells stage (:func:`run_cells`): weighted sample elimination across cells, exact count.

The store's run (:class:`~.eliminate.StoreCells`, resumable), a small input
(:mod:`.small`) and the in-memory API (:func:`eliminate_points`) run the same
functions on the same cells (:class:`ArrayCells` and :class:`ThreadMap`
stand in for the store and the runner), so the kept set does not depend on
where it runs. A task per cell stores its share (:func:`share_task`), the
driver makes exact counts, then the cells are eliminated colour by colour
(:func:`apply_task`; docs/architecture.md, "The default rule `eliminate`").
A crash resumes from the markers: scored cells are not read again and only
cells not done are applied. ``method``, ``cluster_size`` and
``halo_context`` are unused.
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
from .cell_work import task_threads, cell_counts, cell_keep, cell_share, colour_order, halo_rows
from .halo import band_halo

__all__ = ["partition", "ArrayCells", "ThreadMap", "eliminate_cells", "eliminate_points", "share_task", "apply_task",
           "run_cells", "stage_params", "cell_share", "cell_counts", "cell_keep"]


def partition(xyz: np.ndarray, origin: np.ndarray, opts: dict, target: int) -> tuple:
    """:func:`~.partition.build_partition` of the eliminate rule on *xyz*, in memory.

    Returns the :class:`~.partition.Partition` (no store, no runs) and each cell's rows, cell after cell."""
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
    if p > 1:  # each point's label is its own: the store's chunks do not matter
        from .label import label_points

        labels, pairs = label_points(centers, xyz, margin, threads=os.cpu_count() or 1)
    order, bounds = group_rows(labels, p, os.cpu_count() or 1)
    return Partition(centers, np.diff(bounds), *halo_lists(pairs, p), margin, 0, 0, 0, r_max), order


class ArrayCells:
    """The stage's store in memory: points, partition, cell rows, shares, bands and the keep mask in cell order."""

    path = ""  # no store to open

    def __init__(self, xyz: np.ndarray, part, order: np.ndarray, classes: np.ndarray | None = None) -> None:
        self.xyz, self.part, self.order = xyz, part, order
        self.regions = np.cumsum(part.cell_counts) - part.cell_counts
        p = part.n_cells
        self.share, self.bands = [None] * p, [None] * p
        self.keep = np.zeros(len(xyz), dtype=bool)
        self.fill = np.zeros(len(xyz), dtype=bool)  # the gap bound's (max_gap)
        self.markers = np.zeros(p, dtype=bool), np.zeros(p, dtype=bool)  # done, scored: none
        # class policies (module .class_cells): the classes and groups in cell order
        self.codes = None if classes is None else np.asarray(classes)[order]
        self.group = np.zeros(len(xyz), dtype=np.int8)

    def open(self) -> "ArrayCells":
        return self

    def core(self, task) -> np.ndarray:
        return take_rows(self.xyz, self.order[task.region : task.region + self.part.cell_counts[task.cell]])

    def put_share(self, task, core, row, band, copies) -> None:
        self.share[task.cell] = row
        self.bands[task.cell] = core[band], band

    def classes(self, task) -> np.ndarray:
        return self.codes[task.region : task.region + self.part.cell_counts[task.cell]]

    def put_groups(self, task, groups: np.ndarray) -> None:
        self.group[task.region : task.region + len(groups)] = groups

    def groups(self, task, n: int) -> np.ndarray:
        return self.group[task.region : task.region + n]

    def groups_at(self, rows: np.ndarray) -> np.ndarray:
        return self.group[rows]

    def shares(self) -> np.ndarray:
        return np.array(self.share)

    def halo(self, task) -> tuple:
        return band_halo(((s, *self.bands[s]) for s in sorted(task.halo) if len(self.bands[s][1])), task.centers,
                         task.cell, task.margin)

    def keep_at(self, rows: np.ndarray) -> np.ndarray:
        return self.keep[rows]

    def fill_at(self, rows: np.ndarray) -> np.ndarray:
        return self.fill[rows]

    def put_keep(self, task, keep: np.ndarray) -> None:
        self.keep[task.region : task.region + len(keep)] = keep

    def put_fill(self, task, fill: np.ndarray) -> None:
        self.fill[task.region : task.region + len(fill)] = fill

    def input_keep(self) -> np.ndarray:
        """The keep mask in input order (the gap bound's fill included)."""
        keep = np.empty_like(self.keep)
        keep[self.order] = self.keep | self.fill
        return keep


class ThreadMap:
    """The in-memory runner: shares on threads, eliminations in the order given, each task on every core."""

    task_threads = os.cpu_count() or 1

    def __call__(self, func, args, stage: str, after=None) -> list:
        if after is not None:
            return [func(*a) for a in args]
        with ThreadPoolExecutor(self.task_threads) as pool:
            return list(pool.map(lambda a: func(*a), args))


def eliminate_cells(xyz: np.ndarray, part, order: np.ndarray, target, keep_duplicates: bool,
                    policy: tuple | None = None, max_gap: float | None = None,
                    density=None) -> tuple[np.ndarray, int, dict | None]:
    """The keep mask (input order) and distinct points of :func:`run_cells` in memory, and with *max_gap* the
    gap bound's record (:func:`~.gap.run_gap`; else None).

    *policy*: (classes (n,), :class:`~.class_policy.ClassPolicy`) with *target* its groups' targets (G,);
    *density*: a :class:`~.density.DensityTarget`."""
    where = ArrayCells(xyz, part, order, None if policy is None else policy[0])
    params = {"keep_duplicates": keep_duplicates, **stage_params(None if policy is None else policy[1], density)}
    runner = ThreadMap()
    *_, distinct = run_cells(where, part, where.regions, params, runner, target)
    record = None
    if max_gap is not None:
        from .gap import run_gap

        record = run_gap(where, part, where.regions, {**params, "max_gap": float(max_gap)}, runner)
    return where.input_keep(), distinct, record


def eliminate_points(xyz: np.ndarray, target: int, *, seed: int, cluster_size: int, k0: float, k_min: int,
                     keep_duplicates: bool) -> np.ndarray:
    """The keep mask (n,) of *xyz* (n, 3) reduced to *target* points as an engine run keeps it.

    The in-memory API's rule ``eliminate``; uses the default ``cell_size``."""
    from ..chunk import xyz_bounds
    from ..params import COMMANDS

    opts = {"cell_size": COMMANDS["simplify"]["cell_size"].default, "seed": seed, "cluster_size": cluster_size,
            "k0": k0, "k_min": k_min}
    part, order = partition(xyz, np.asarray(xyz_bounds(xyz)[0], dtype=np.float64), opts, int(target))
    return eliminate_cells(xyz, part, order, int(target), keep_duplicates)[0]


def stage_params(policy, density) -> dict:
    """The cells stage's parameters of a :class:`~.class_policy.ClassPolicy` (its groups) or a
    :class:`~.density.DensityTarget` (the areas' side and floor); empty for neither."""
    if density is not None:
        return {"density_cell": density.side, "density_floor": density.floor, "density_dims": density.dims}
    return {} if policy is None else {"lookup": policy.lookup.tolist(), "groups": policy.groups}


def share_task(where, task, dependents: dict) -> dict[str, Any]:
    """A task: one cell's share (:func:`cell_share`) computed and stored in *where* (store or :class:`ArrayCells`).

    *dependents*: int -> centre of the cells whose halo may hold its points.
    The halo is not read (most of a cell's reading); the border packings only
    grow slightly, alike in every cell, and the shares only split an exact total.
    Returns "cell", "n", "band", "share" (the row stored) and "seconds".
    """
    t0 = time.perf_counter()
    io = where.open()
    core = io.core(task)
    areas = None
    if task.params.get("groups"):  # class policies: a share per group
        from .class_cells import group_share

        row, band, copies = group_share(io, task, core, dependents)
    else:
        if task.params.get("density_cell"):  # the density target: the cell's points per area
            from .density import area_counts, area_keys

            areas = area_counts(area_keys(core, float(task.params["density_cell"]), int(task.params["density_dims"])))
        sizes, distinct, band = cell_share(core, float(task.params["r_max"]), task.centers, task.cell, dependents,
                                           task.margin, task_threads(task), ladder=task.params["ladder"])
        row, copies = np.r_[float(distinct), sizes], len(core) - distinct
    io.put_share(task, core, row, band, copies)
    return {"cell": task.cell, "n": len(core), "band": len(band), "share": row, "areas": areas,
            "seconds": time.perf_counter() - t0}


def apply_task(where, task, count, colours: dict) -> dict[str, Any]:
    """A task: one cell of *where* eliminated to *count* points (:func:`cell_keep`), its keep mask stored.

    *colours*: int -> colour of the cell and its halo sources. Lower colours'
    final decisions are fixed, higher colours' points are halo, eliminated
    along but not counted. With class policies *count* is a list, a count per
    group (:func:`.class_cells.group_keep`). Returns "cell", "n", "kept", "seconds"."""
    t0 = time.perf_counter()
    io = where.open()
    core = io.core(task)
    if task.params.get("groups") or task.params.get("density_cell"):
        from .class_cells import group_keep
        from .density import density_keep

        keep = (density_keep if task.params.get("density_cell") else group_keep)(io, task, core, count, colours)
        io.put_keep(task, keep)
        return {"cell": task.cell, "n": len(core), "kept": int(keep.sum()), "seconds": time.perf_counter() - t0}
    n, halo = len(core), None
    if 0 < count < n:  # else no elimination: no halo
        points, rows, fixed = halo_rows(io, task, colours)
        halo_keep = np.zeros(len(points), dtype=bool)
        if fixed.any():  # their final decisions
            halo_keep[fixed] = io.keep_at(rows[fixed])
        halo = points, fixed, halo_keep
    keep = cell_keep(core, count, float(task.params["r_max"]), halo, task_threads(task), task.params.get("staged"),
                     task.params.get("keep_duplicates"))
    io.put_keep(task, keep)
    return {"cell": task.cell, "n": n, "kept": int(keep.sum()), "seconds": time.perf_counter() - t0}


def run_cells(where, part, regions: np.ndarray, params: dict, runner, target: int) -> tuple[int, int, int, int]:
    """The eliminate rule's cells stage on *where*, only for cells not marked (resume).

    *where*: the work store or :class:`ArrayCells` (``markers`` (done,
    scored), ``shares()``, and ``open()`` for a task's I/O); *part*: built
    for this target (``part.r_max`` set); *regions*: (P,) int64; *runner*:
    ``runner(func, args, stage, after=None)``, results in order, ``after[i]``
    the calls call i waits for, and ``runner.task_threads``; *target*: points
    kept in all. With ``params["density_cell"]`` (:mod:`.density`) every cell
    is scored again (its areas are not stored) and gets a quota per area.
    Returns (cells applied, cells found done, points scored, distinct points).
    """
    from ..core.colours import apply_order, cell_colours, readers
    from .celltasks import cell_tasks, largest_first

    r_max = math.inf if part.r_max is None else float(part.r_max)
    density = params.get("density_cell")  # the density target: every cell's areas, no packings
    params = {**params, "r_max": r_max, "ladder": part.n_cells > 1 and not density}  # one cell's count is the target
    done, scored = where.markers
    todo = largest_first(part, [j for j in range(part.n_cells) if density or not scored[j]])
    tasks = cell_tasks(where, part, regions, todo, params, runner.task_threads, halo=False)
    deps = readers(part.halo_ptr, part.halo_src)  # the cells that read each cell's band
    args = [(where, t, {int(i): part.centers[i] for i in deps[t.cell]}) for t in tasks]
    results = runner(share_task, args, "cells: share")
    # the shares of this run's tasks from their results; the store's only for cells scored before (resume)
    fresh = results and len(todo) == part.n_cells
    share = np.zeros((part.n_cells, len(results[0]["share"]))) if fresh else where.shares()
    for r in results:
        share[r["cell"]] = r["share"]
    if params.get("groups"):  # class policies: counts per cell and group, each group's summing to its target
        from .class_cells import group_counts

        q, params["staged"], distinct = group_counts(share, np.asarray(target), r_max)
    elif density:  # a quota per (cell, area), each dense area's summing to its floor
        from .density import area_quotas

        areas = [None] * part.n_cells
        for r in results:
            areas[r["cell"]] = r["areas"]
        q, distinct = area_quotas(areas, int(params["density_floor"])), share[:, 0].astype(np.int64)
    else:
        distinct = share[:, 0].astype(np.int64)
        q, params["staged"] = cell_counts(share[:, 1:], distinct, int(target), r_max)
    colours = cell_colours(part.halo_ptr, part.halo_src)
    # a cell starts once the lower-colour cells of its halo are done
    ordered = apply_order(colours, part.cell_counts, [j for j in range(part.n_cells) if not done[j]])
    tasks = cell_tasks(where, part, regions, ordered, params, runner.task_threads, halo=True)
    cols, after = colour_order(tasks, colours)
    args = [(where, t, q[t.cell].tolist(), c) for t, c in zip(tasks, cols)]
    runner(apply_task, args, "cells: apply", after=after)
    return len(ordered), int(done.sum()), int(sum(r["n"] for r in results)), int(distinct.sum())
