"""The cells stage of the ``eliminate`` rule: weighted sample elimination across cells, exact count.

The in-memory rule (:mod:`cloudsieve.core.eliminate`) run out of core:

1. **r_max** -- one global elimination radius, solved before the cells on
   the partition's uniform sample (:func:`global_radius`, called by
   :func:`cloudsieve.engine.partition.build_partition`, recorded in the
   partition's attributes, so a resumed run uses the same one); the halo
   margin is at least 2.2 r_max (the elimination and the relocation reach
   2 r_max).
2. **pass 1** (:func:`score_task`, one task per cell):
   :func:`~cloudsieve.core.eliminate.eliminate_order` of the cell's points
   with its halo (the neighbours' points within the margin, eliminated with
   the cell but given no priority), the full order (no ``floor``: a cell's
   early stop would only give upper bounds on the priorities of the points
   it left, and nothing bounds where the global cut falls in a cell's
   order). Stored as score = -priority in ``simplify/score_cells`` (lower
   goes first: exact copies -inf), then ``simplify/scored[cell]``.
3. **the cut** (:func:`cloudsieve.engine.cut.exact_cut`): T and the tie
   quotas that remove exactly N - target points, ties by cell then by index.
4. **pass 2** (:func:`apply_task`), colour by colour
   (:func:`~cloudsieve.engine.colours.cell_colours`: cells that share a
   halo never share a colour; one runner call per colour, its cells in
   parallel): each cell keeps exactly its count under the cut, q_j (score >
   T, and its ties after its quota). A cell of colour 0 keeps those points;
   a cell of a higher colour runs the elimination again with the FINAL
   decisions of its lower-colour neighbours (their kept points fixed: they
   weigh, never go; their removed points gone: represented by their nearest
   point, so the coverage term sees the area they leave) and the points of
   its higher-colour neighbours as halo, and keeps the q_j points removed
   last. Without this both sides of a border remove their border points,
   each expecting the other's to stay: holes at the borders (autzen_trim at
   50% in 14 cells: point max 0.387% of the diagonal against 0.161% in
   memory; 0.176% with fixed points only, 0.161% with the gone ones). Then one
   restricted Lloyd step, :func:`~cloudsieve.core.eliminate.relocate`, with
   the halo's points kept as decided: the final masks of the lower colours,
   the cut's decisions of the higher ones. The count does not change.
   Writes ``simplify/keep_cells``, then ``simplify/done[cell]``.

A crash anywhere resumes from the markers: cells scored or done are not
scored again, the cut is recomputed from the stored scores (the same), and
only the cells not done are applied, colour by colour (the colours are a
pure function of the partition; a cell reads only lower colours' results,
all done before its colour starts).

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
from .colours import cell_colours
from .cut import exact_cut, keep_mask
from .halo import read_halo
from .runs import cell_runs, read_cell

__all__ = ["global_radius", "score_task", "apply_task", "run_eliminate"]


def global_radius(sample: np.ndarray, n: int, target: int) -> float:
    """The one r_max of a cloud of *n* points keeping *target*, from a uniform sample of it.

    :func:`~cloudsieve.core.radius.point_areas` on the sample (S points) are
    areas at the sample's density: scaled by S / n to the cloud's, each
    standing for n / S of its points, they give
    :func:`~cloudsieve.core.radius.elimination_radius`. With the whole cloud
    as the sample (S = n <= 50,000) this is the r_max of
    :func:`cloudsieve.core.eliminate.eliminate`.

    Parameters
    ----------
    sample : ndarray of shape (S, 3), float64
    n : int
        Points in the cloud.
    target : int
        Points kept.

    Returns
    -------
    float
        r_max; inf when every point is kept (or nothing is: *target* 0).
    """
    from ..core.radius import elimination_radius, point_areas

    s = len(sample)
    if target <= 0 or s == 0:
        return math.inf
    areas, weight = point_areas(sample)
    return float(elimination_radius(areas * (s / n), int(target), weight=weight * n / s))


# ---------------------------------------------------------------- the tasks


def _threads(task: CellTask) -> int:
    return int(task.params.get("threads") or 1)


def _read(task: CellTask, return_index: bool = False):
    """The store's group, the cell's runs, its points (n, 3) and its halo (and the halo's cells and positions)."""
    from ..store import PointStore

    g = PointStore.open(task.store_path, "r+").group
    runs = cell_runs(g, task.cell)
    sources = {int(s): cell_runs(g, int(s)) for s in task.halo}
    halo = read_halo(g, sources, task.centers, task.cell, task.margin, return_index=return_index)
    return g, runs, read_cell(g, runs), halo


def score_task(task: CellTask) -> dict[str, Any]:
    """Pass 1: the elimination order of one cell with its halo, stored as score = -priority (a task).

    ``task.params["r_max"]`` is the global radius.

    Returns
    -------
    dict with "cell", "n", "halo", "seconds" (small).
    """
    from ..core.eliminate import eliminate_order

    t0 = time.perf_counter()
    g, _, core, halo = _read(task)
    n = len(core)
    score = np.zeros(n)
    if n:
        prio = eliminate_order(core, r_max=float(task.params["r_max"]), halo=halo, threads=_threads(task))
        score = np.negative(prio) + 0.0  # lower goes first; + 0.0: no -0.0
    g["simplify/score_cells"][task.region : task.region + n] = score
    g["simplify/scored"][task.cell : task.cell + 1] = np.ones(1, dtype=np.uint8)
    return {"cell": task.cell, "n": n, "halo": len(halo), "seconds": time.perf_counter() - t0}


def _halo_keep(g, task: CellTask, cells: np.ndarray, pos: np.ndarray, threshold: float, ties: dict) -> np.ndarray:
    """Which halo points their own cells keep under the cut (before their relocation)."""
    sc = g["simplify/score_cells"]
    keep = np.zeros(len(cells), dtype=bool)
    for s, region in task.halo.items():
        sel = np.flatnonzero(cells == s)
        if not len(sel):
            continue
        quota, equal = ties[s]
        if 0 < quota < equal:  # a tie split inside cell s: the ranks need the whole cell
            n_s = int(pos[sel].max()) + 1
            keep[sel] = keep_mask(np.asarray(sc[region : region + n_s]), threshold, quota)[pos[sel]]
        else:
            s_sel = np.asarray(sc.get_orthogonal_selection((region + pos[sel],)))
            keep[sel] = (s_sel > threshold) | ((s_sel == threshold) & (quota == 0))
    return keep


def _final_keep(g, task: CellTask, cells: np.ndarray, pos: np.ndarray, sources) -> np.ndarray:
    """The final keep decisions (``simplify/keep_cells``) of the halo points of cells *sources*."""
    kc = g["simplify/keep_cells"]
    keep = np.zeros(len(cells), dtype=bool)
    for s in sources:
        sel = np.flatnonzero(cells == s)
        if len(sel):
            keep[sel] = np.asarray(kc.get_orthogonal_selection((task.halo[s] + pos[sel],)))
    return keep


def apply_task(task: CellTask, threshold: float, ties: dict, colours: dict | None = None) -> dict[str, Any]:
    """Pass 2: keep as many of the cell's points as the cut keeps, relocate once, write the keep mask (a task).

    The cut gives the cell its count q (score > T, and its ties after its
    quota). A cell with no halo source of a lower colour keeps those points
    (its pass-1 order is the one it would compute again). Otherwise the
    elimination runs again with the final decisions of the lower colours
    (kept: fixed points, they weigh, never go; removed: gone) and the points of the higher
    colours as halo (thinned with the cell), and keeps the q points removed
    last: a neighbour's removed points are given as ``gone`` (represented by
    their nearest point), so the two sides of a border do not both open a
    hole there.

    Parameters
    ----------
    task : CellTask
    threshold : float
        T of the :class:`~cloudsieve.engine.cut.Cut`.
    ties : dict int -> (int, int)
        (quota, equal) of the cut for the cell and each of its halo sources.
    colours : dict int -> int, optional
        Colour (:func:`~cloudsieve.engine.colours.cell_colours`) of the cell
        and of each of its halo sources; cells of lower colours must be done.
        None: every cell one colour (the cut's decisions, no re-run).

    Returns
    -------
    dict with "cell", "n", "kept", "rerun", "seconds" (small).
    """
    from ..core.eliminate import eliminate_order, keep_lowest, relocate

    t0 = time.perf_counter()
    r_max = float(task.params["r_max"])
    g, runs, core, (halo, cells, pos) = _read(task, return_index=True)
    n = len(core)
    keep = keep_mask(np.asarray(g["simplify/score_cells"][task.region : task.region + n]), threshold,
                     ties[task.cell][0])
    mine = 0 if colours is None else colours[task.cell]
    earlier = [s for s in task.halo if colours is not None and colours[s] < mine]
    rerun = bool(earlier) and n > 0 and 0 < keep.sum() < n and math.isfinite(r_max)
    if n and keep.any() and math.isfinite(r_max):
        halo_keep = _halo_keep(g, task, cells, pos, threshold, ties)  # the later colours: their pass-1 decisions
        if earlier:
            fixed = np.isin(cells, earlier)
            halo_keep[fixed] = _final_keep(g, task, cells, pos, earlier)[fixed]
            if rerun:
                prio = eliminate_order(core, r_max=r_max, halo=halo[~fixed], fixed=halo[fixed & halo_keep],
                                       gone=halo[fixed & ~halo_keep], threads=_threads(task))
                keep = keep_lowest(prio, int(keep.sum()))
        keep = relocate(core, keep, r_max, halo=halo, halo_keep=halo_keep, threads=_threads(task))
    g["simplify/keep_cells"][task.region : task.region + n] = keep
    g["simplify/done"][task.cell : task.cell + 1] = np.ones(1, dtype=np.uint8)
    return {"cell": task.cell, "n": n, "kept": int(keep.sum()), "rerun": rerun,
            "seconds": time.perf_counter() - t0}


# ---------------------------------------------------------------- the stage


def run_eliminate(store, part, regions: np.ndarray, params: dict, runner, target: int) -> tuple[int, int, int, float]:
    """The cells stage of the eliminate rule: pass 1, the exact cut, pass 2 (resumable).

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
    (computed, reused, points, priority) : cells applied now, cells found done, points scored now,
        and the priority at the cut (points above it went; -T)
    """
    r_max = math.inf if part.r_max is None else float(part.r_max)
    params = {**params, "r_max": r_max}
    done = np.asarray(store.group["simplify/done"][:]).astype(bool)
    scored = np.asarray(store.group["simplify/scored"][:]).astype(bool)
    todo = largest_first(part, [j for j in range(part.n_cells) if not scored[j] and not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads, halo=True)
    results = runner(score_task, [(t,) for t in tasks], "cells: score")
    cut = exact_cut(store, part, regions, runner, store.count - int(target))
    todo = [j for j in range(part.n_cells) if not done[j]]
    colours = cell_colours(part.halo_ptr, part.halo_src)
    for c in range(int(colours.max()) + 1 if len(colours) else 0):  # a colour reads the lower ones' results
        tasks = cell_tasks(store, part, regions, largest_first(part, [j for j in todo if colours[j] == c]), params,
                           runner.task_threads, halo=True)
        args = []
        for t in tasks:
            ties = {int(s): (int(cut.quotas[s]), int(cut.equal[s])) for s in (t.cell, *t.halo)}
            args.append((t, cut.threshold, ties, {int(s): int(colours[s]) for s in (t.cell, *t.halo)}))
        runner(apply_task, args, "cells: apply")
    return len(todo), int(done.sum()), int(sum(r["n"] for r in results)), -cut.threshold
