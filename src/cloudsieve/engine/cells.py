"""Stage 3, cells: one dask task per cell runs the in-memory method on the cell's points.

A task (its :class:`CellTask` argument does not grow with P) reads its core
points, and its halo with a density context, calls the core with the seed
``SeedSequence([seed, cell])``, writes its own region of
``simplify/keep_cells`` and marks ``simplify/done[cell]``. Targets
(``ratio=`` / ``count=``) take two passes around the global threshold T
(:mod:`.threshold`): :func:`score_task` stores labels and unit-free scores;
:func:`apply_task` keeps score > T, or for a ``cell_count`` rule the same
number chosen by the core's rule. With ``params["context"]`` the cell's
halo is every cluster's density context (the paper: each cluster alone).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..core.rules import CELL_COUNT, PAPER_THRESHOLD
from ..core.rules import get as get_rule
from .celltasks import CellTask, cell_tasks, largest_first
from .halo import read_halo
from .runs import cell_runs, read_runs

__all__ = [
    "CellTask",
    "cell_seed",
    "cell_tasks",
    "largest_first",
    "thinned_halo",
    "cell_task",
    "score_task",
    "apply_task",
    "run_keep",
    "run_score",
    "run_apply",
]


def cell_seed(seed: int, cell: int) -> int:
    """The seed of cell *cell*: ``SeedSequence([seed, cell])``, as a 32-bit int."""
    return int(np.random.SeedSequence([int(seed), int(cell)]).generate_state(1, np.uint32)[0])


def _halo_runs(group, halo: dict) -> dict:
    """The runs of the halo source cells, read from the store: {source: runs}."""
    return {int(s): cell_runs(group, int(s)) for s in halo}


def _open_cell(task: CellTask):
    """The store's group, the cell's core points (n, 3) and its halo points (h, 3)."""
    from ..store import PointStore

    g = PointStore.open(task.store_path, "r+").group
    core = read_runs(g, cell_runs(g, task.cell))
    sources = _halo_runs(g, task.halo)
    halo = read_halo(g, sources, task.centers, task.cell, task.margin)
    return g, core, halo


def thinned_halo(group, task: CellTask, threshold: float) -> np.ndarray:
    """The halo points (h, 3) whose own cell's pass-1 score exceeds T (those the target keeps).

    A halo left at full density would make border points look redundant
    over pass 2's rounds (a seam); the pass-1 decisions are the best
    deterministic guess of the neighbours' final density.
    """
    sources = _halo_runs(group, task.halo)
    pts, cells, pos = read_halo(group, sources, task.centers, task.cell, task.margin, return_index=True)
    if not len(pts):
        return pts
    sc = group["simplify/score_cells"]
    keep = np.empty(len(pts), dtype=bool)
    for s, region in task.halo.items():
        sel = np.flatnonzero(cells == s)
        if len(sel):
            keep[sel] = np.asarray(sc.get_orthogonal_selection((region + pos[sel],))) > threshold
    return pts[keep]


def _context(params: dict, halo: np.ndarray | None):
    """The density context handed to the core: the halo (possibly empty), or None (R alone)."""
    return halo if params["context"] else None


def _threads(params: dict) -> int:
    """k-d tree threads of a cell task (:attr:`Runner.task_threads`); results do not depend on it."""
    return int(params.get("threads") or 1)


def _simplify(core, params: dict, cell: int, *, threshold, target, labels, context) -> np.ndarray:
    """The kept indices of the in-memory method on one cell (options already validated, so unchecked)."""
    from ..core.simplify import simplify_unchecked
    from ..params_spec import OPTION_CLASSES

    ctx = None if context is None else np.ascontiguousarray(context, dtype=np.float64).reshape(-1, 3)
    options = OPTION_CLASSES["simplify_points"](
        method=params["method"], rule=params["rule"], threshold=threshold, cluster_size=params["cluster_size"],
        seed=cell_seed(params["seed"], cell), k0=params["k0"], k_min=params["k_min"], score="delta_h",
        threads=_threads(params), keep_duplicates=bool(params.get("keep_duplicates")))
    return simplify_unchecked(np.ascontiguousarray(core, dtype=np.float64), options, target=target, ctx=ctx,
                              labels=labels)


def _mark_done(g, name: str, cell: int) -> None:
    g[name][cell : cell + 1] = np.ones(1, dtype=np.uint8)


def _record_duplicates(g, cell: int, n_copies: int) -> None:
    """The cell's count of exact duplicates, in ``simplify/duplicates``."""
    g["simplify/duplicates"][cell : cell + 1] = np.full(1, n_copies, dtype=np.int64)


def cell_task(task: CellTask) -> dict[str, Any]:
    """Task: simplify one cell with a threshold rule; writes ``simplify/keep_cells`` then ``simplify/done[cell]``.

    Returns "cell", "n", "kept", "halo", "duplicates", "seconds".
    """
    from ..core import exact_copies

    t0 = time.perf_counter()
    params, cell, region = task.params, task.cell, task.region
    g, core, halo = _open_cell(task)
    n = len(core)
    keep = np.zeros(n, dtype=bool)
    n_copies = 0
    if n:
        n_copies = int(exact_copies(core).sum())
        kept = _simplify(core, params, cell, threshold=params["threshold"], target=None, labels=None,
                         context=_context(params, halo))
        keep[np.asarray(kept, dtype=np.int64)] = True
    g["simplify/keep_cells"][region : region + n] = keep
    _record_duplicates(g, cell, n_copies)
    _mark_done(g, "simplify/done", cell)
    return {"cell": int(cell), "n": int(n), "kept": int(keep.sum()), "halo": int(len(halo)),
            "duplicates": n_copies, "seconds": time.perf_counter() - t0}


def score_task(task: CellTask) -> dict[str, Any]:
    """Pass-1 task of a ratio/count: refine and score one cell (unit-free m*dH).

    Writes ``simplify/score_cells`` and ``simplify/label_cells``, then
    ``simplify/scored[cell]``. Returns "cell", "n", "halo", "seconds".
    """
    from ..core import exact_copies, refine_labels, score_points

    t0 = time.perf_counter()
    params, cell, region = task.params, task.cell, task.region
    g, core, halo = _open_cell(task)
    n = len(core)
    scores = np.zeros(n, dtype=np.float64)
    labels = np.zeros(n, dtype=np.int64)
    if n:  # options validated once: the unchecked calls
        labels = refine_labels.unchecked(
            core, params["method"], params["cluster_size"], cell_seed(params["seed"], cell), k_min=params["k_min"],
            threads=_threads(params),
        )
        scores = np.asarray(
            score_points.unchecked(core, labels, context=_context(params, halo), k0=params["k0"], k_min=params["k_min"],
                                   threads=_threads(params)).unit_free,
            dtype=np.float64,
        )
        labels[exact_copies(core)] = -1  # pass 2 drops them (or keeps them with their first copy)
    g["simplify/score_cells"][region : region + n] = scores
    g["simplify/label_cells"][region : region + n] = labels.astype(np.int32)
    _mark_done(g, "simplify/scored", cell)
    return {"cell": int(cell), "n": int(n), "halo": int(len(halo)), "seconds": time.perf_counter() - t0}


def apply_task(task: CellTask, threshold: float) -> dict[str, Any]:
    """Pass-2 task of a ratio/count: apply the global threshold T to one cell.

    A ``global_threshold`` rule keeps score > T; a ``cell_count`` rule keeps as
    many points, chosen by the core's rule on the stored clusters. Returns
    "cell", "n", "kept", "seconds".
    """
    from ..core import first_copies
    from ..store import PointStore

    t0 = time.perf_counter()
    params, cell, region = task.params, task.cell, task.region
    g = PointStore.open(task.store_path, "r+").group
    runs = cell_runs(g, cell)
    n = int(runs[:, 2].sum() - runs[:, 1].sum()) if len(runs) else 0
    s = np.asarray(g["simplify/score_cells"][region : region + n])
    labels = np.asarray(g["simplify/label_cells"][region : region + n]).astype(np.int64)
    copy = labels < 0  # exact copies (pass 1)
    keep = (s > threshold) & ~copy
    by_count = get_rule(params["rule"]).engine == CELL_COUNT  # else: the global threshold decides
    need_points = by_count or (copy.any() and bool(params.get("keep_duplicates")))
    core = read_runs(g, runs) if n and need_points else None
    if not by_count and core is not None:  # copies follow their first point
        keep = keep[first_copies(core)]
    elif by_count and n:
        halo = thinned_halo(g, task, threshold) if params["context"] else None
        kept = _simplify(core, params, cell, threshold=PAPER_THRESHOLD, target=int(keep.sum()), labels=labels,
                         context=_context(params, halo))
        keep = np.zeros(n, dtype=bool)
        keep[np.asarray(kept, dtype=np.int64)] = True
    g["simplify/keep_cells"][region : region + n] = keep
    _record_duplicates(g, cell, int(copy.sum()))
    _mark_done(g, "simplify/done", cell)
    return {"cell": int(cell), "n": int(n), "kept": int(keep.sum()), "seconds": time.perf_counter() - t0}


def _marked(store, name: str) -> np.ndarray:
    """Which cells are marked in ``simplify/<name>`` ("done" or "scored"), bool (P,)."""
    return np.asarray(store.group[f"simplify/{name}"][:]).astype(bool)


def run_keep(store, part, regions: np.ndarray, params: dict, runner) -> tuple[int, int, int]:
    """Threshold-rule cells stage: a :func:`cell_task` per cell not done; (computed, reused, points)."""
    done = _marked(store, "done")
    todo = largest_first(part, [j for j in range(part.n_cells) if not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads)
    results = runner(cell_task, [(t,) for t in tasks], "cells")
    return len(todo), int(done.sum()), int(sum(r["n"] for r in results))


def run_score(store, part, regions: np.ndarray, params: dict, runner) -> tuple[int, int]:
    """Pass 1: a :func:`score_task` per cell neither scored nor done; (reused, points scored)."""
    done = _marked(store, "done")
    scored = _marked(store, "scored")
    todo = largest_first(part, [j for j in range(part.n_cells) if not scored[j] and not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads)
    results = runner(score_task, [(t,) for t in tasks], "cells: score")
    return int(done.sum()), int(sum(r["n"] for r in results))


def run_apply(store, part, regions: np.ndarray, params: dict, runner, threshold: float) -> int:
    """Pass 2: an :func:`apply_task` with threshold T per cell not done; the cells computed."""
    done = _marked(store, "done")
    todo = largest_first(part, [j for j in range(part.n_cells) if not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads)
    runner(apply_task, [(t, threshold) for t in tasks], "cells: apply")
    return len(todo)
