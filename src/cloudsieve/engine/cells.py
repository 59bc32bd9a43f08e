"""Stage 3, cells: one dask task per cell runs the in-memory method on the cell's points.

A cell task opens the store by path, reads its core points (and, with a
density context, its halo) from its runs, calls the core
(:func:`cloudsieve.core.simplify_points`: refine into clusters of
~cluster_size, score, rule) with the cell's seed ``SeedSequence([seed,
cell])``, writes its keep mask into its own region of
``simplify/keep_cells`` and marks the cell done in ``simplify/done`` (one
zarr chunk per cell, so concurrent writers never share a chunk). Its
argument, a :class:`CellTask`, is small: it does not grow with the number of
cells P.

Targets (``ratio=`` / ``count=``) run two passes around the global threshold
T (:mod:`cloudsieve.engine.threshold`):

- pass 1, :func:`score_task`: :func:`cloudsieve.core.refine_labels` and
  :func:`cloudsieve.core.unit_free_scores` (m*dH, comparable across clusters
  and cells), stored in ``simplify/label_cells`` and ``simplify/score_cells``;
- pass 2, :func:`apply_task`: a rule whose registry ``engine`` is
  ``global_threshold`` (``target``) keeps score > T, the one-pass threshold
  on the unit-free score m*dH; a ``cell_count`` rule (``iterative``,
  ``coverage``) keeps in each cell as many
  points as the target rule would (n_j - #{score <= T}), chosen by the core's
  rule with that count on the stored clusters (``simplify_points(labels=...,
  count=...)``), so the removals follow the scores across cells and the total
  is the target rule's.

Density context: by default each small cluster is scored alone (the paper;
the core's default), so a cell border is just another cluster border. With
``params["context"]`` the cell's halo is the density context of every
cluster; pass 2 then uses the halo thinned by the neighbours' pass-1
decisions (:func:`thinned_halo`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..core.rules import CELL_COUNT, PAPER_THRESHOLD
from ..core.rules import get as get_rule
from .celltasks import CellTask, cell_tasks, largest_first
from .halo import read_halo
from .runs import cell_runs, read_cell

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


# ---------------------------------------------------------------- reading a cell


def _halo_runs(group, halo: dict) -> dict:
    """The runs of the halo source cells, read from the store: {source: runs}."""
    return {int(s): cell_runs(group, int(s)) for s in halo}


def _open_cell(task: CellTask):
    """The store's group, the cell's core points (n, 3) and its halo points (h, 3)."""
    from ..store import PointStore

    g = PointStore.open(task.store_path, "r+").group
    core = read_cell(g, cell_runs(g, task.cell))
    sources = _halo_runs(g, task.halo)
    halo = read_halo(g, sources, task.centers, task.cell, task.margin)
    return g, core, halo


def thinned_halo(group, task: CellTask, threshold: float) -> np.ndarray:
    """The halo points whose own cell's pass-1 score exceeds T (those the target keeps).

    Pass 2 of an iterative ratio/count thins the cell over several rounds; a
    halo left at full density would make the points near the border look
    redundant and thin them more (a seam). The neighbours' pass-1 decisions
    are the best deterministic guess of their final density.

    Returns
    -------
    ndarray of shape (h, 3), float64
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
    """k-d tree threads of a cell task (see :attr:`Runner.task_threads`); the results do not depend on it."""
    return int(params.get("threads") or 1)


def _core_kwargs(params: dict) -> dict:
    return {"k0": params["k0"], "k_min": params["k_min"], "threads": _threads(params)}


def _simplify(core, params: dict, cell: int, *, threshold, target, labels, context) -> np.ndarray:
    """The in-memory method on one cell (:func:`cloudsieve.core.simplify.simplify_unchecked`: the run's
    options were validated once, by :func:`cloudsieve.engine.simplify`): the kept indices."""
    from ..core.simplify import simplify_unchecked
    from ..params_spec import OPTION_CLASSES

    ctx = None if context is None else np.ascontiguousarray(context, dtype=np.float64).reshape(-1, 3)
    options = OPTION_CLASSES["simplify_points"](
        method=params["method"], rule=params["rule"], threshold=threshold, cluster_size=params["cluster_size"],
        seed=cell_seed(params["seed"], cell), k0=params["k0"], k_min=params["k_min"], score="delta_h",
        threads=_threads(params), keep_duplicates=_keep_duplicates(params))
    return simplify_unchecked(np.ascontiguousarray(core, dtype=np.float64), options, target=target, ctx=ctx,
                              labels=labels)


def _mark_done(g, name: str, cell: int) -> None:
    g[name][cell : cell + 1] = np.ones(1, dtype=np.uint8)


def _record_duplicates(g, cell: int, n_copies: int) -> None:
    """The cell's count of exact duplicate points, in ``simplify/duplicates`` (summed by the summary)."""
    g["simplify/duplicates"][cell : cell + 1] = np.full(1, n_copies, dtype=np.int64)


def _keep_duplicates(params: dict) -> bool:
    return bool(params.get("keep_duplicates", False))


# ---------------------------------------------------------------- the tasks


def cell_task(task: CellTask) -> dict[str, Any]:
    """Simplify one cell with a threshold rule (a dask task): core + halo in, keep mask out.

    Calls :func:`cloudsieve.core.simplify_points` (refine, score, rule) with
    the cell's seed and its halo as density context. Writes
    ``simplify/keep_cells[region:region + n]`` then ``simplify/done[cell]``.

    Returns
    -------
    dict with "cell", "n", "kept", "halo", "duplicates", "seconds" (small).
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
    """Pass 1 of a ratio/count: refine one cell and score it (a dask task).

    :func:`cloudsieve.core.refine_labels` then
    :func:`cloudsieve.core.unit_free_scores` (m*dH, comparable across cells).
    Writes ``simplify/score_cells`` and ``simplify/label_cells`` in the cell's
    region, then ``simplify/scored[cell]``.

    Returns
    -------
    dict with "cell", "n", "halo", "seconds" (small).
    """
    from ..core import exact_copies, refine_labels, score_points

    t0 = time.perf_counter()
    params, cell, region = task.params, task.cell, task.region
    g, core, halo = _open_cell(task)
    n = len(core)
    scores = np.zeros(n, dtype=np.float64)
    labels = np.zeros(n, dtype=np.int64)
    if n:  # the run's options were validated once (engine.simplify): the unchecked calls
        labels = refine_labels.unchecked(
            core, params["method"], params["cluster_size"], cell_seed(params["seed"], cell), k_min=params["k_min"],
            threads=_threads(params),
        )
        scores = np.asarray(
            score_points.unchecked(core, labels, context=_context(params, halo), **_core_kwargs(params)).unit_free,
            dtype=np.float64,
        )
        labels[exact_copies(core)] = -1  # pass 2 drops them (or keeps them with their first copy)
    g["simplify/score_cells"][region : region + n] = scores
    g["simplify/label_cells"][region : region + n] = labels.astype(np.int32)
    _mark_done(g, "simplify/scored", cell)
    return {"cell": int(cell), "n": int(n), "halo": int(len(halo)), "seconds": time.perf_counter() - t0}


def apply_task(task: CellTask, threshold: float) -> dict[str, Any]:
    """Pass 2 of a ratio/count: apply the global threshold T to one cell (a dask task).

    A ``global_threshold`` rule of the registry (``target``): keep the points
    with score > T (the one-pass threshold on the same unit-free scores).
    A ``cell_count`` rule (``iterative``, ``coverage``): the cell keeps as many points as the
    target rule would (n - #{score <= T}), chosen by the core's rule on the
    stored clusters (``simplify_points(labels=..., count=...)``).

    Returns
    -------
    dict with "cell", "n", "kept", "seconds" (small).
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
    need_points = by_count or (copy.any() and _keep_duplicates(params))
    core = read_cell(g, runs) if n and need_points else None
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


# ---------------------------------------------------------------- the stage


def _marked(store, name: str) -> np.ndarray:
    """Which cells are marked in ``simplify/<name>`` ("done" or "scored"), bool (P,)."""
    return np.asarray(store.group[f"simplify/{name}"][:]).astype(bool)


def run_keep(store, part, regions: np.ndarray, params: dict, runner) -> tuple[int, int, int]:
    """The cells stage of a threshold rule: a :func:`cell_task` for every cell not done yet.

    Returns
    -------
    (computed, reused, points) : cells computed now, cells found done, points in the computed cells
    """
    done = _marked(store, "done")
    todo = largest_first(part, [j for j in range(part.n_cells) if not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads)
    results = runner(cell_task, [(t,) for t in tasks], "cells")
    return len(todo), int(done.sum()), int(sum(r["n"] for r in results))


def run_score(store, part, regions: np.ndarray, params: dict, runner) -> tuple[int, int]:
    """Pass 1 of a ratio/count: a :func:`score_task` for every cell neither scored nor done.

    Returns
    -------
    (reused, points) : cells found done, points in the cells scored now
    """
    done = _marked(store, "done")
    scored = _marked(store, "scored")
    todo = largest_first(part, [j for j in range(part.n_cells) if not scored[j] and not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads)
    results = runner(score_task, [(t,) for t in tasks], "cells: score")
    return int(done.sum()), int(sum(r["n"] for r in results))


def run_apply(store, part, regions: np.ndarray, params: dict, runner, threshold: float) -> int:
    """Pass 2 of a ratio/count: an :func:`apply_task` with threshold T for every cell not done.

    Returns
    -------
    int : cells computed now
    """
    done = _marked(store, "done")
    todo = largest_first(part, [j for j in range(part.n_cells) if not done[j]])
    tasks = cell_tasks(store, part, regions, todo, params, runner.task_threads)
    runner(apply_task, [(t, threshold) for t in tasks], "cells: apply")
    return len(todo)
