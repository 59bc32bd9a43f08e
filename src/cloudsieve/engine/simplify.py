"""Out-of-core, distributed simplification: the whole pipeline as dask tasks.

:func:`simplify` runs, each stage reading and writing the point store:

1. **ingest** (when SRC is a file) into a work store, see *store* below;
2. **partition** (:mod:`cloudsieve.partition`): P = ceil(N / cell_size) coarse
   K-means cells, bucketed out of core, with halos;
3. **cells**: one dask task per cell reads its core (and, with
   ``context=True``, its halo) from the store, runs the in-memory method
   (:func:`cloudsieve.prune.simplify_points`: refine into clusters of
   ~cluster_size, score, rule) with a seed derived from (seed, cell id), writes the cell's keep mask into its own zarr chunks of
   ``simplify/keep_cells`` and marks the cell done in ``simplify/done``
   (one zarr chunk per cell, so concurrent writers never share a chunk);
4. **merge**: one task per input chunk scatters the keep masks back to input
   order as ``simplify/keep``;
5. **export** of the kept points, every attribute and the header
   (:func:`cloudsieve.store.export`, atomic).

Only a few numbers pass through the scheduler, never an array of size P or
N: every task opens the store by path and reads its own runs there (see
:mod:`cloudsieve.partition`); a cell task gets the centres of its cell and of
its halo sources. Results do not depend on the
scheduler, the number of workers or task completion order: a cell's points
are in input order, its seed is ``SeedSequence([seed, cell])``, and every
reduction is over integers or in a fixed order.

Targets (``ratio=`` / ``count=``) across cells
    Pass 1 (one task per cell): :func:`cloudsieve.prune.refine_labels` and
    :func:`cloudsieve.prune.unit_free_scores` (m*dH, comparable across
    clusters and cells), stored in ``simplify/label_cells`` and
    ``simplify/score_cells``. The global threshold T is then chosen so that
    N - target points score <= T: summed per-cell histograms of log10(score)
    narrow it to a bin, whose few scores are gathered and T picked exactly with
    :func:`cloudsieve.prune.threshold_for_count` (exact up to equal scores).
    Pass 2 (one task per cell): rule ``"target"`` keeps score > T, which is
    ``prune(rule="threshold", score="unit_free", threshold=T)`` on the same
    scores; rules ``"iterative"``/``"coverage"`` keep in each cell as many
    points as the target rule would (n_j - #{score <= T}), chosen by the
    core's rule with that count on the stored clusters
    (``simplify_points(labels=..., count=...)``), so the removals follow the
    scores across cells and the total is the target rule's: within 1% of the
    request (exact but for ties).

Work store
    When SRC is a file it is ingested into *store*, by default
    ``DST + ".cloudsieve.zarr"`` beside DST; that default store is deleted after
    a successful run (pass ``store=`` to keep it). A run that crashed leaves it
    in place, and a rerun (``resume=True``, or simply the same command) reuses
    the ingest, the partition and every completed cell, after checking that the
    source file and the parameters are the same (:class:`ResumeMismatchError`
    otherwise; ``overwrite=True`` starts again). When SRC is a store, the
    derived arrays are written into it.

Density context
    By default each small cluster is scored alone (the paper; the core's
    default), so a cell border is just another cluster border and the result
    is that of the in-memory method with a two-level clustering. With
    ``context=True`` the cell and its halo are the density neighbours of every
    cluster (see the *context* parameter for the measured seams).

Scheduler
    ``None`` (the embedded default): dask's local ``"processes"`` scheduler
    with one process pool for the whole run (measured on 2 cores, 2 M points,
    KM: cells stage 88 s with processes, 128 s with threads: the in-memory
    method holds the GIL in its Python parts); with ``memory_limit`` a
    :class:`distributed.LocalCluster` of *workers* processes, each capped.
    ``"sync"``, ``"threads"``, ``"processes"``: dask's local schedulers.
    ``"tcp://host:port"`` or ``client=``: an existing dask.distributed
    cluster whose workers can reach the store path.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from . import partition as _part
from ..errors import (
    CloudsieveError,
    DestinationExistsError,
    InvalidParameterError,
    ResumeMismatchError,
    SameSourceDestinationError,
)
from ..progress import callback
from ..store import DEFAULT_CHUNK_SIZE

__all__ = ["simplify", "Summary", "DEFAULT_SCHEDULER", "SIMPLIFY_ATTR", "cell_seed"]

logger = logging.getLogger(__name__)

SIMPLIFY_ATTR = "cloudsieve_simplify"
ENGINE_VERSION = 1
#: the embedded default local scheduler (measured faster than threads: see the module docstring)
DEFAULT_SCHEDULER = "processes"
#: histogram of log10(score) used to choose a global threshold
_HIST_LO, _HIST_HI, _HIST_BINS = -16.0, 4.0, 4000
#: tasks a local worker process runs before it is replaced (bounds heap growth)
_TASKS_PER_CHILD = 8
#: gather the scores of the threshold's bin once it holds at most this many
_GATHER_MAX = 200_000


# ---------------------------------------------------------------- summary


@dataclass
class Summary:
    """What a :func:`simplify` run did.

    Attributes
    ----------
    points_in, kept, removed : int
    cells : int
        Number of cells P.
    cells_computed, cells_reused : int
        Cells computed in this run, and cells found done in the store (resume).
    threshold : float or None
        The global threshold on the unit-free score chosen for a ratio/count
        (None otherwise).
    seconds : dict str -> float
        Wall time per stage ("ingest", "partition", "cells", "merge",
        "export") and "total".
    peak_memory : int
        Peak resident memory of this process and its children (bytes), sampled.
    scheduler : str
    source, destination, store : str
    """

    points_in: int = 0
    kept: int = 0
    removed: int = 0
    cells: int = 0
    cells_computed: int = 0
    cells_reused: int = 0
    threshold: float | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    scheduler: str = ""
    source: str = ""
    destination: str = ""
    store: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def __str__(self) -> str:
        s = self
        pct = 100.0 * s.kept / s.points_in if s.points_in else 0.0
        rate = s.points_in / s.seconds["total"] if s.seconds.get("total") else 0.0
        lines = [
            f"points in     {s.points_in:>14,}",
            f"kept          {s.kept:>14,}  ({pct:.2f}%)",
            f"removed       {s.removed:>14,}",
            f"cells         {s.cells:>14,}  (computed {s.cells_computed}, reused {s.cells_reused})",
        ]
        if s.threshold is not None:
            lines.append(f"threshold     {s.threshold:>14.6g}  (global, on m*dH)")
        stages = ", ".join(f"{k} {v:.2f}s" for k, v in s.seconds.items() if k != "total")
        lines.append(f"time          {s.seconds.get('total', 0.0):>13.2f}s  ({stages}); {rate:,.0f} points/s")
        lines.append(f"peak memory   {s.peak_memory / 2**20:>12.0f} MiB  (this process and its children)")
        lines.append(f"scheduler     {s.scheduler}")
        return "\n".join(lines)


class _PeakMemory:
    """Samples the resident memory of this process and its children in a thread."""

    def __init__(self, interval: float = 0.1) -> None:
        self.interval = interval
        self.peak = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def sample(self) -> int:
        try:
            import psutil
        except ImportError:  # pragma: no cover
            import resource

            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        proc = psutil.Process()
        total = 0
        for p in [proc, *proc.children(recursive=True)]:
            with contextlib.suppress(Exception):
                total += p.memory_info().rss
        return total

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            self.peak = max(self.peak, self.sample())

    def __enter__(self) -> _PeakMemory:
        self.peak = self.sample()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="cloudsieve-peak-memory")
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.peak = max(self.peak, self.sample())


# ---------------------------------------------------------------- runner

#: modules imported once by the fork server, so a replaced worker starts in milliseconds
_PRELOAD = ["numpy", "scipy.spatial", "zarr", "cloudsieve.store", "cloudsieve.engine.partition", "cloudsieve.core",
            "cloudsieve.engine"]


def _worker_context():
    """The multiprocessing context of the local worker processes.

    dask's default is "spawn": every new process starts Python and imports
    numpy, scipy, zarr and cloudsieve again (~1.3 s measured), and workers are
    replaced every ``_TASKS_PER_CHILD`` tasks. Where available (and unless
    dask's ``multiprocessing.context`` is configured) a "forkserver" that has
    imported them once forks the workers instead: a clean single-threaded
    parent, like spawn, without the start-up cost.
    """
    import multiprocessing as mp

    import dask
    from dask.multiprocessing import get_context

    if dask.config.get("multiprocessing.context", None) is None and "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(_PRELOAD)
        return ctx
    return get_context()



class _Runner:
    """Runs batches of independent tasks on the chosen dask scheduler.

    ``runner(func, argument_tuples, stage)`` returns the results in the order
    of the arguments, whatever the completion order.
    """

    def __init__(self, scheduler=None, workers=None, memory_limit=None, client=None, bars=None) -> None:
        self.client = client
        self._own_client = False
        self._cluster = None
        self.workers = workers
        self.bars = bars
        if client is not None:
            self.name = f"distributed ({getattr(client, 'scheduler', None) and client.scheduler.address})"
            return
        if isinstance(scheduler, str) and "://" in scheduler:
            from distributed import Client

            self.client = Client(scheduler)
            self._own_client = True
            self.name = f"distributed ({scheduler})"
            return
        if memory_limit is not None:
            if scheduler not in (None, "processes"):
                raise InvalidParameterError(
                    f"memory_limit ({memory_limit}) needs worker processes: use the default scheduler or 'processes', not {scheduler!r}"
                )
            from distributed import Client, LocalCluster

            n = int(workers or os.cpu_count() or 1)
            self._cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                memory_limit=memory_limit,
                host="127.0.0.1",
                dashboard_address=None,
            )
            self.client = Client(self._cluster)
            self._own_client = True
            self.name = f"local cluster ({n} workers, memory limit {memory_limit})"
            return
        if scheduler is None:
            scheduler = DEFAULT_SCHEDULER
        if scheduler not in ("sync", "synchronous", "threads", "processes"):
            raise InvalidParameterError(
                f"unknown scheduler {scheduler!r}: use sync, threads, processes or a tcp://host:port address"
            )
        self.local = "sync" if scheduler == "synchronous" else scheduler
        self.name = self.local + (f" ({workers} workers)" if workers and self.local != "sync" else "")
        self._pool = None
        if self.local == "processes":
            # one pool for the whole run: dask would start (and import into) a
            # new pool at every compute() otherwise, seconds per stage
            from concurrent.futures import ProcessPoolExecutor

            # a worker process is replaced after a few tasks: long-lived
            # processes keep the high-water mark of the allocator (fragmented
            # heaps of many cells), so the peak memory would creep with N
            self._pool = ProcessPoolExecutor(
                int(workers or os.cpu_count() or 1), mp_context=_worker_context(), max_tasks_per_child=_TASKS_PER_CHILD
            )

    @property
    def task_threads(self) -> int:
        """k-d tree threads for each cell task: the machine's cores shared by the tasks running at once.

        Without this every task queries with all cores (the core's
        default): 2 worker processes on 2 cores ran 4 k-d tree threads. A
        single worker still gets every core (its queries are threaded). On a
        dask.distributed cluster the workers' threads are assumed to fill
        their machines: 1. The results do not depend on it.
        """
        cores = os.cpu_count() or 1
        if self.client is not None and self._cluster is None:
            return 1
        if getattr(self, "local", None) == "sync":
            return cores
        return max(1, cores // int(self.workers or cores))

    @property
    def dashboard_link(self) -> str | None:
        if self.client is None:
            return None
        with contextlib.suppress(Exception):
            return self.client.dashboard_link
        return None

    def close(self) -> None:
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._own_client and self.client is not None:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()

    def __call__(self, func: Callable, args: Sequence[tuple], stage: str, unit: str = "task") -> list:
        args = list(args)
        if not args:
            return []
        bar = self.bars(stage, len(args), unit) if self.bars is not None else contextlib.nullcontext(None)
        with bar as update:
            update = callback(update)
            if self.client is not None:
                return self._distributed(func, args, stage, update)
            return self._local(func, args, update)

    def _distributed(self, func, args, stage, update) -> list:
        from distributed import as_completed

        token = uuid.uuid4().hex[:8]
        tag = stage.replace(" ", "").replace(":", "-")
        futures = [
            self.client.submit(func, *a, key=f"cloudsieve-{tag}-{i}-{token}", pure=False) for i, a in enumerate(args)
        ]
        try:
            for _ in as_completed(futures):
                update(1)
            return self.client.gather(futures)
        finally:
            for f in futures:
                f.release()

    def _local(self, func, args, update) -> list:
        import dask
        from dask.callbacks import Callback

        # keys that sort in reverse argument order: dask's local scheduler then
        # starts the tasks in argument order (with random keys it picks them
        # in key order, i.e. at random), which the cells stage uses to start
        # the largest cells first
        token = uuid.uuid4().hex[:8]
        last = len(args) - 1
        tasks = [
            dask.delayed(func, pure=False)(*a, dask_key_name=f"cloudsieve-{func.__name__}-{token}-{last - i:09d}")
            for i, a in enumerate(args)
        ]
        keys = {t.key for t in tasks}

        class _Count(Callback):
            def _posttask(self, key, result, dsk, state, worker_id):
                if key in keys:
                    update(1)

        kwargs = {"scheduler": self.local}
        if self.workers and self.local != "sync":
            kwargs["num_workers"] = int(self.workers)
        if self._pool is not None:
            kwargs["pool"] = self._pool
            kwargs["chunksize"] = 1  # dask batches 6 tasks per submission by default: 6 cells on one worker
        with _Count():
            return list(dask.compute(*tasks, **kwargs))


# ---------------------------------------------------------------- cell tasks


def cell_seed(seed: int, cell: int) -> int:
    """The seed of cell *cell*: ``SeedSequence([seed, cell])``, as a 32-bit int."""
    return int(np.random.SeedSequence([int(seed), int(cell)]).generate_state(1, np.uint32)[0])


def _halo_runs(group, halo: dict) -> dict:
    """The runs of the halo source cells, read from the store: {source: runs}."""
    return {int(s): _part.cell_runs(group, int(s)) for s in halo}


def _cell_points(group, centers, margin, cell, runs, halo):
    core = _part.read_cell(group, runs)
    pts = _part.read_halo(group, _halo_runs(group, halo), centers, cell, margin)
    return core, pts


def _thinned_halo(group, centers, margin, cell, halo: dict, threshold: float) -> np.ndarray:
    """The halo points whose own cell's pass-1 score exceeds T (those the target keeps).

    Pass 2 of an iterative ratio/count thins the cell over several rounds; a
    halo left at full density would make the points near the border look
    redundant and thin them more (a seam). The neighbours' pass-1 decisions
    are the best deterministic guess of their final density.
    """
    pts, cells, pos = _part.read_halo(group, _halo_runs(group, halo), centers, cell, margin, return_index=True)
    if not len(pts):
        return pts
    sc = group["simplify/score_cells"]
    keep = np.empty(len(pts), dtype=bool)
    for s, region in halo.items():
        sel = np.flatnonzero(cells == s)
        if len(sel):
            keep[sel] = np.asarray(sc.get_orthogonal_selection((region + pos[sel],))) > threshold
    return pts[keep]


def _context(params: dict, halo: np.ndarray):
    """The density context handed to the core: the halo (possibly empty), or None (R alone)."""
    return halo if params["context"] else None


def _core_kwargs(params: dict) -> dict:
    return {"k0": params["k0"], "k_min": params["k_min"], "workers": _threads(params)}


def _threads(params: dict) -> int:
    """k-d tree threads of a cell task (see :meth:`_Runner.task_threads`); the results do not depend on it."""
    return int(params.get("threads") or 1)


def _open_cell(store_path: str, cell: int, halo, centers, margin):
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    g = st.group
    core, pts = _cell_points(g, centers, margin, cell, _part.cell_runs(g, cell), halo)
    return g, core, pts


def _mark_done(g, name: str, cell: int) -> None:
    g[name][cell : cell + 1] = np.ones(1, dtype=np.uint8)


def cell_task(store_path: str, cell: int, halo: dict, centers: dict, margin: float, region: int, params: dict) -> dict:
    """Simplify one cell with a threshold rule (a dask task): core + halo in, keep mask out.

    Calls :func:`cloudsieve.prune.simplify_points` (refine, score, rule) with
    the cell's seed and its halo as density context. The task reads its runs
    (and its halo sources') from the store; its arguments are small: *halo*
    maps each halo source cell to its region, *centers* maps the cell and its
    halo sources to their centres. Writes
    ``simplify/keep_cells[region:region + n]`` then ``simplify/done[cell]``.

    Returns
    -------
    dict with "cell", "n", "kept", "halo", "seconds" (small).
    """
    from ..core.prune import simplify_points

    t0 = time.perf_counter()
    g, core, halo = _open_cell(store_path, cell, halo, centers, margin)
    n = len(core)
    keep = np.zeros(n, dtype=bool)
    if n:
        kept = simplify_points(
            core,
            method=params["method"],
            rule=params["rule"],
            threshold=params["threshold"],
            cluster_size=params["cluster_size"],
            seed=cell_seed(params["seed"], cell),
            context=_context(params, halo),
            **_core_kwargs(params),
        )
        keep[np.asarray(kept, dtype=np.int64)] = True
    g["simplify/keep_cells"][region : region + n] = keep
    _mark_done(g, "simplify/done", cell)
    return {"cell": int(cell), "n": int(n), "kept": int(keep.sum()), "halo": int(len(halo)), "seconds": time.perf_counter() - t0}


def score_task(store_path: str, cell: int, halo: dict, centers: dict, margin: float, region: int, params: dict) -> dict:
    """Pass 1 of a ratio/count: refine one cell and score it (a dask task).

    :func:`cloudsieve.prune.refine_labels` then
    :func:`cloudsieve.prune.unit_free_scores` (m*dH, comparable across cells).
    Writes ``simplify/score_cells`` and ``simplify/label_cells`` in the cell's
    region, then ``simplify/scored[cell]``.
    """
    from ..core.prune import refine_labels, unit_free_scores

    t0 = time.perf_counter()
    g, core, halo = _open_cell(store_path, cell, halo, centers, margin)
    n = len(core)
    scores = np.zeros(n, dtype=np.float64)
    labels = np.zeros(n, dtype=np.int64)
    if n:
        labels = refine_labels(
            core, params["method"], params["cluster_size"], cell_seed(params["seed"], cell), k_min=params["k_min"],
            workers=_threads(params),
        )
        scores = np.asarray(
            unit_free_scores(core, labels, context=_context(params, halo), **_core_kwargs(params)), dtype=np.float64
        )
    g["simplify/score_cells"][region : region + n] = scores
    g["simplify/label_cells"][region : region + n] = labels.astype(np.int32)
    _mark_done(g, "simplify/scored", cell)
    return {"cell": int(cell), "n": int(n), "halo": int(len(halo)), "seconds": time.perf_counter() - t0}


def _score_hist_task(store_path: str, region: int, n: int, lo: float, hi: float, bins: int) -> np.ndarray:
    """Histogram of log10 of one cell's stored scores over [lo, hi), plus under/over counts.

    Returns
    -------
    ndarray of shape (bins + 2,), int64: [below lo, bins..., at or above hi]
    """
    from ..store import PointStore

    st = PointStore.open(store_path, "r")
    s = np.asarray(st.group["simplify/score_cells"][region : region + n])
    with np.errstate(divide="ignore"):
        ls = np.log10(s)
    out = np.zeros(bins + 2, dtype=np.int64)
    out[0] = int((ls < lo).sum())
    out[-1] = int((ls >= hi).sum())
    inside = ls[(ls >= lo) & (ls < hi)]
    idx = np.minimum(((inside - lo) / (hi - lo) * bins).astype(np.int64), bins - 1)
    out[1:-1] = np.bincount(idx, minlength=bins)
    return out


def _scores_between_task(store_path: str, region: int, n: int, lo: float, hi: float) -> np.ndarray:
    """The stored scores of one cell with lo <= log10(score) < hi (few, by construction)."""
    from ..store import PointStore

    st = PointStore.open(store_path, "r")
    s = np.asarray(st.group["simplify/score_cells"][region : region + n])
    with np.errstate(divide="ignore"):
        ls = np.log10(s)
    return s[(ls >= lo) & (ls < hi)]


def apply_task(
    store_path: str, cell: int, halo: dict, centers: dict, margin: float, region: int, params: dict, threshold: float
) -> dict:
    """Pass 2 of a ratio/count: apply the global threshold T to one cell (a dask task).

    rule "target": keep the points with score > T (what
    ``prune(rule="threshold", score="unit_free", threshold=T)`` does on the same
    scores). rules "iterative"/"coverage": the cell keeps as many points as the
    target rule would (n - #{score <= T}), chosen by the core's rule on the
    stored clusters (``simplify_points(labels=..., count=...)``).
    """
    from ..core.prune import simplify_points
    from ..store import PointStore

    t0 = time.perf_counter()
    st = PointStore.open(store_path, "r+")
    g = st.group
    runs = _part.cell_runs(g, cell)
    n = int(runs[:, 2].sum() - runs[:, 1].sum()) if len(runs) else 0
    s = np.asarray(g["simplify/score_cells"][region : region + n])
    keep = s > threshold
    if params["rule"] != "target" and n:
        core = _part.read_cell(g, runs)
        halo = _thinned_halo(g, centers, margin, cell, halo, threshold) if params["context"] else None
        labels = np.asarray(g["simplify/label_cells"][region : region + n]).astype(np.int64)
        kept = simplify_points(
            core,
            method=params["method"],
            rule=params["rule"],
            count=int(keep.sum()),
            cluster_size=params["cluster_size"],
            seed=cell_seed(params["seed"], cell),
            labels=labels,
            context=_context(params, halo),
            **_core_kwargs(params),
        )
        keep = np.zeros(n, dtype=bool)
        keep[np.asarray(kept, dtype=np.int64)] = True
    g["simplify/keep_cells"][region : region + n] = keep
    _mark_done(g, "simplify/done", cell)
    return {"cell": int(cell), "n": int(n), "kept": int(keep.sum()), "seconds": time.perf_counter() - t0}


def merge_task(store_path: str, chunk: int, start: int, stop: int) -> int:
    """Scatter the cells' keep masks back to input order for input chunk *chunk*, points ``[start, stop)``.

    Reads the chunk's runs (``partition/chunk_runs``) and their cells' regions
    (``simplify/regions``) from the store, so its arguments do not grow with P.

    Returns
    -------
    int : kept points in the chunk.
    """
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    g = st.group
    runs = _part.chunk_runs(g, chunk)  # (cell, count, first), cells increasing
    n = stop - start
    if int(runs[:, 1].sum()) != n:  # pragma: no cover - the partition is inconsistent
        raise CloudsieveError(f"{store_path}: chunk at {start} has {n} points but its cells hold {int(runs[:, 1].sum())}")
    labels = np.asarray(g["partition/cell"][start:stop]).astype(np.int64)
    order = np.argsort(labels, kind="stable")
    regions = np.asarray(g["simplify/regions"].get_coordinate_selection(runs[:, 0])) if len(runs) else np.empty(0, np.int64)
    # positions in the cell-ordered arrays of the chunk's points, sorted by cell (each run contiguous)
    begin = regions + runs[:, 2]
    idx = np.repeat(begin - np.cumsum(runs[:, 1]) + runs[:, 1], runs[:, 1]) + np.arange(n)
    sorted_keep = np.asarray(g["simplify/keep_cells"].get_coordinate_selection(idx)) if n else np.empty(0, bool)
    keep = np.empty(n, dtype=bool)
    keep[order] = sorted_keep
    g["simplify/keep"][start:stop] = keep
    return int(keep.sum())


# ---------------------------------------------------------------- helpers


def _source_identity(src: str) -> dict:
    st = os.stat(src)
    return {"path": os.path.abspath(src), "size": int(st.st_size), "mtime_ns": int(st.st_mtime_ns)}


def _regions(cell_counts: np.ndarray, block: int) -> tuple[np.ndarray, int]:
    """Start of each cell's region in the cell-ordered arrays, aligned to *block*."""
    padded = -(-cell_counts // block) * block
    padded = np.maximum(padded, 0)
    starts = np.zeros(len(cell_counts), dtype=np.int64)
    np.cumsum(padded[:-1], out=starts[1:])
    total = int(padded.sum())
    return starts, max(total, block)


def _region_block(cell_size: int) -> int:
    """zarr chunk of the cell-ordered arrays: a power of two near cell_size / 16."""
    b = 1 << max(10, min(16, int(math.log2(max(1, cell_size // 16)))))
    return b


def _params(method, rule, threshold, ratio, count, cluster_size, cell_size, seed, context, k0, k_min) -> dict:
    return {
        "version": ENGINE_VERSION,
        "method": method,
        "rule": rule,
        "threshold": float(threshold),
        "ratio": None if ratio is None else float(ratio),
        "count": None if count is None else int(count),
        "cluster_size": int(cluster_size),
        "cell_size": int(cell_size),
        "seed": int(seed),
        "context": bool(context),
        "k0": float(k0),
        "k_min": int(k_min),
    }


def _check_args(method, rule, threshold, ratio, count, cluster_size, cell_size) -> str:
    if method not in ("km", "fcm"):
        raise InvalidParameterError(f"method must be 'km' or 'fcm', got {method!r}")
    if rule not in ("iterative", "threshold", "target", "coverage"):
        raise InvalidParameterError(f"rule must be 'iterative', 'threshold', 'target' or 'coverage', got {rule!r}")
    if ratio is not None and count is not None:
        raise InvalidParameterError(f"give ratio or count, not both (got ratio={ratio}, count={count})")
    if ratio is not None and not (0.0 <= float(ratio) <= 1.0):
        raise InvalidParameterError(f"ratio is the kept fraction, in [0, 1], got {ratio}")
    if count is not None and (int(count) != count or int(count) < 0):
        raise InvalidParameterError(f"count must be an integer >= 0, got {count}")
    has_target = ratio is not None or count is not None
    if rule in ("target", "coverage") and not has_target:
        raise InvalidParameterError(f"rule {rule!r} needs a ratio or a count")
    if rule == "threshold" and has_target:
        raise InvalidParameterError(
            f"rule 'threshold' takes a threshold only, not ratio={ratio}/count={count}: use rule 'target' or 'iterative'"
        )
    if not (math.isfinite(threshold) and threshold >= 0):
        raise InvalidParameterError(f"threshold must be a finite number >= 0, got {threshold}")
    if int(cluster_size) < 6:
        raise InvalidParameterError(f"cluster_size must be >= 6 (k_min + 2), got {cluster_size}")
    if int(cell_size) < int(cluster_size):
        raise InvalidParameterError(f"cell_size ({cell_size}) must be >= cluster_size ({cluster_size})")
    return rule


# ---------------------------------------------------------------- simplify


def simplify(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    method: str = "fcm",
    rule: str = "iterative",
    threshold: float = 1e-3,
    ratio: float | None = None,
    count: int | None = None,
    cluster_size: int = 400,
    cell_size: int = 100_000,
    scheduler: str | None = None,
    workers: int | None = None,
    memory_limit: str | int | None = None,
    store: str | os.PathLike | None = None,
    seed: int = 0,
    resume: bool = False,
    client=None,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
    bars=None,
    notify: Callable[[str], None] | None = None,
    format: str | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    context: bool = False,
    k0: float = 1.0,
    k_min: int = 4,
) -> Summary:
    """Simplify a point cloud of any size, out of core, on dask.

    Parameters
    ----------
    src : str or path-like
        Input file (any format :mod:`cloudsieve.io` reads) or a point store.
    dst : str or path-like
        Output file (any format :mod:`cloudsieve.io` writes), written atomically.
    method : {"fcm", "km"}
        Refinement into small clusters: fuzzy C-means or K-means.
    rule : {"iterative", "threshold", "target"}
        Pruning rule (see :mod:`cloudsieve.prune`).
    threshold : float
        S, the entropy-change threshold of the threshold/iterative rules.
    ratio, count : float or int, optional
        Keep this share / number of the input points instead of using S
        (one of them; required by ``rule="target"``). The total lands within
        1% of the request.
    cluster_size : int
        Points per small cluster (c = ceil(n / cluster_size) per cell).
    cell_size : int
        Points per coarse cell, i.e. per task; bounds a task's memory. The
        in-memory method peaks at about 2 kB per point, and K-means cells
        vary (largest ~1.3x the mean). Measured on 2 cores, 2 workers, KM,
        10 M points (benchmarks/engine.py): peak RSS of the process tree
        1.26 GB with 100,000 (the default), 1.97 GB with 250,000, at the same
        throughput.
    scheduler : str, optional
        None (embedded default), "sync", "threads", "processes" or a
        "tcp://host:port" dask.distributed scheduler address.
    workers : int, optional
        Local worker count (threads/processes/LocalCluster).
    memory_limit : str or int, optional
        Per-worker memory cap ("1GB"); runs a LocalCluster of *workers* processes.
    store : str or path-like, optional
        Work store for a file SRC (local path or fsspec URL). Default:
        ``DST + ".cloudsieve.zarr"``, deleted after success.
    seed : int
        One seed for everything; the output is the same bit for bit on any
        scheduler and worker count.
    resume : bool
        Continue the run recorded in the work store: reuse its ingest, its
        partition and every cell marked done. A rerun with the same store
        does so anyway (the flag states the intent; without a store to
        resume the run starts from the beginning, with a log message).
    client : distributed.Client, optional
        Run on this cluster (workers must reach the store path).
    overwrite : bool
        Overwrite DST, and discard a work store left by another run.
    progress : callable, optional
        ``progress(n)`` after n points of a stage are processed.
    bars : callable, optional
        ``bars(stage, total, unit)`` -> context manager yielding ``update(n)``
        (e.g. :func:`cloudsieve.progress.bar`): one progress bar per stage.
    notify : callable, optional
        ``notify(message)`` for what a user should see at once (the dask
        dashboard link of a distributed run); the CLI prints it.
    format : str, optional
        Output format (default: by DST's extension).
    chunk_size : int
        Points per chunk of the ingested store.
    context : bool
        False (default): density neighbours come from each small cluster R
        alone (the paper; the core's default), and a cell border is just
        another cluster border. True: the cell's halo and the whole cell are
        the density context of every cluster (``context=`` of the core).
        Measured on a uniform plane cut into 8 cells and pruned to 50%: kept
        density within one cluster radius of the cell borders / interior =
        0.98-0.99 with False, 0.94-0.95 with True (the halo is thinned by
        the pass-1 decisions, see :func:`_thinned_halo`; 0.91 unthinned).
    k0, k_min : float, int
        The k-NN rule k = max(k_min, round(k0 * sqrt(m))).

    Returns
    -------
    Summary
        Also stored in the store's attributes under ``"cloudsieve_simplify"``.

    Raises
    ------
    ResumeMismatchError
        The work store holds a run with other parameters or another source.
    DestinationExistsError
        DST exists and *overwrite* is False.
    """
    from ..store import PointStore, delete_store, export, ingest, is_store, local_path

    t_start = time.perf_counter()
    src, dst = os.fspath(src), os.fspath(dst)
    rule = _check_args(method, rule, threshold, ratio, count, cluster_size, cell_size)
    params = _params(method, rule, threshold, ratio, count, cluster_size, cell_size, seed, context, k0, k_min)
    update = callback(progress)
    summary = Summary(source=src, destination=dst)
    dst_local = local_path(dst)
    if dst_local is not None and os.path.exists(dst_local) and not overwrite:
        raise DestinationExistsError(f"{dst} exists (pass overwrite=True / --overwrite to replace it)")
    if local_path(src) is not None and dst_local is not None and os.path.abspath(local_path(src)) == dst_local:
        raise SameSourceDestinationError(f"{dst} is the source: cloudsieve never overwrites its input")

    src_is_store = is_store(src)
    default_store = store is None and not src_is_store
    if src_is_store:
        store_path = src
    else:
        store_path = os.fspath(store) if store is not None else dst + ".cloudsieve.zarr"
    if "://" not in store_path:
        store_path = os.path.abspath(store_path)  # workers may run elsewhere (another cwd)

    with _PeakMemory() as peak:
        runner = _Runner(scheduler, workers, memory_limit, client, bars)
        summary.scheduler = runner.name
        if runner.dashboard_link:
            logger.info("dask dashboard: %s", runner.dashboard_link)
            if notify is not None:
                notify(f"dask dashboard: {runner.dashboard_link}")
        try:
            # ---------------------------------------------------- ingest
            t0 = time.perf_counter()
            st = None
            if src_is_store:
                st = PointStore.open(store_path, "r+")
            else:
                identity = _source_identity(src)
                existing = is_store(store_path)
                if existing and overwrite:
                    delete_store(store_path)
                    existing = False
                if resume and not existing:
                    logger.info("resume: no complete work store at %s, starting from the ingest", store_path)
                if existing:
                    st = PointStore.open(store_path, "r+")
                    rec = st.attrs.get(SIMPLIFY_ATTR, {}).get("source")
                    if rec is not None and (rec["size"], rec["mtime_ns"]) != (identity["size"], identity["mtime_ns"]):
                        raise ResumeMismatchError(
                            f"work store {store_path} was ingested from {rec['path']} "
                            f"({rec['size']} bytes, mtime {rec['mtime_ns']}), not from {src} "
                            f"({identity['size']} bytes, mtime {identity['mtime_ns']}); pass overwrite=True (--overwrite) to start again"
                        )
                    logger.info("reusing the ingest in %s", store_path)
                else:
                    with _stage_bar(bars, "ingest", None, "pt") as bupd:
                        def _up(n, bupd=bupd):
                            bupd(n)
                            update(n)

                        st = ingest(src, store_path, chunk_size=chunk_size, overwrite=True, progress=_up)
                    st = PointStore.open(store_path, "r+")
                    st.group.attrs.update({SIMPLIFY_ATTR: {"source": identity}})
            summary.store = store_path
            summary.points_in = st.count
            summary.seconds["ingest"] = time.perf_counter() - t0

            # ---------------------------------------------------- resume check
            rec = dict(st.attrs.get(SIMPLIFY_ATTR, {}))
            old = rec.get("params")
            if old is not None and old != params:
                if not overwrite:
                    diff = {k: (old.get(k), params[k]) for k in params if old.get(k) != params[k]}
                    raise ResumeMismatchError(
                        f"store {store_path} holds a run with other parameters "
                        + ", ".join(f"{k}: stored {a!r}, asked {b!r}" for k, (a, b) in diff.items())
                        + "; pass overwrite=True (--overwrite) to discard it"
                    )
                old = None
            if old is None:
                _clear_derived(st)
            rec["params"] = params
            rec.pop("summary", None)
            st.group.attrs.update({SIMPLIFY_ATTR: rec})

            # ---------------------------------------------------- partition
            t0 = time.perf_counter()
            meta = st.attrs.get(_part.PARTITION_ATTR)
            want = {"cell_size": int(cell_size), "cluster_size": int(cluster_size), "seed": int(seed)}
            complete = isinstance(meta, dict) and meta.get("complete")
            if complete and meta.get("version") != _part.PARTITION_VERSION:
                # an older layout (version 1: a dense chunks x cells table): rebuilt, with the cells
                logger.info(
                    "the partition in %s has layout version %s (this version writes %d): partitioning again",
                    store_path, meta.get("version"), _part.PARTITION_VERSION,
                )
                complete = False
            if complete and all(meta.get(k) == v for k, v in want.items()) and (meta.get("halo") or not context):
                part = _part.Partition.load(st)
                logger.info("reusing the partition in %s (%d cells)", store_path, part.n_cells)
            else:
                _clear_derived(st)
                part = _part.build_partition(
                    st, cell_size=cell_size, cluster_size=cluster_size, seed=seed, run=runner, k0=k0, k_min=k_min,
                    halo=bool(context),  # the halo sources are only read with a density context
                )
            update(st.count)
            summary.cells = part.n_cells
            summary.seconds["partition"] = time.perf_counter() - t0

            # ---------------------------------------------------- cells
            t0 = time.perf_counter()
            cell_counts = part.cell_counts
            block = _region_block(cell_size)
            regions, total = _regions(cell_counts, block)
            _ensure_cell_arrays(st, part.n_cells, total, block, regions)
            target = None
            if ratio is not None:
                target = int(round(float(ratio) * st.count))
            elif count is not None:
                target = min(int(count), st.count)
            computed, reused, threshold_used = _run_cells(
                st, part, regions, params, runner, target, update
            )
            summary.cells_computed, summary.cells_reused = computed, reused
            summary.threshold = threshold_used
            summary.seconds["cells"] = time.perf_counter() - t0

            # ---------------------------------------------------- merge
            t0 = time.perf_counter()
            n = st.count
            if "simplify/keep" not in st.group:
                st.group.create_array(
                    "simplify/keep", shape=(n,), dtype="bool", chunks=(st.chunk_size,), fill_value=False,
                    compressors=_compressors(),
                )
            args = [(store_path, c, s, min(s + st.chunk_size, n)) for c, s in enumerate(range(0, n, st.chunk_size))]
            kept_chunks = runner(merge_task, args, "merge")
            summary.kept = int(sum(kept_chunks))
            summary.removed = summary.points_in - summary.kept
            update(n)
            summary.seconds["merge"] = time.perf_counter() - t0

            # ---------------------------------------------------- export
            t0 = time.perf_counter()
            with _stage_bar(bars, "export", n, "pt") as bupd:
                def _up2(k, bupd=bupd):
                    bupd(k)
                    update(k)

                export(st, dst, format=format, mask="simplify/keep", overwrite=overwrite, progress=_up2)
            summary.seconds["export"] = time.perf_counter() - t0
        finally:
            runner.close()
    summary.seconds["total"] = time.perf_counter() - t_start
    summary.peak_memory = int(peak.peak)
    rec = dict(st.attrs.get(SIMPLIFY_ATTR, {}))
    rec["summary"] = summary.to_dict()
    st.group.attrs.update({SIMPLIFY_ATTR: rec})
    if default_store:
        delete_store(store_path)
        summary.store = ""
    logger.info("simplify %s -> %s: %d of %d points kept", src, dst, summary.kept, summary.points_in)
    return summary


def _compressors():
    from ..store import compressors

    return compressors()


@contextlib.contextmanager
def _stage_bar(bars, stage, total, unit):
    if bars is None:
        yield callback(None)
    else:
        with bars(stage, total, unit) as upd:
            yield callback(upd)


def _clear_derived(st) -> None:
    """Delete the simplify arrays (they depend on the partition and the parameters)."""
    g = st.group
    if "simplify" in g:
        del g["simplify"]


def _ensure_cell_arrays(st, n_cells: int, total: int, block: int, regions: np.ndarray) -> None:
    g = st.group
    comp = _compressors()
    if "simplify/keep_cells" in g and g["simplify/keep_cells"].shape == (total,) and "simplify/regions" in g:
        return
    for name in ("keep_cells", "score_cells", "label_cells", "done", "scored", "keep", "regions"):
        if f"simplify/{name}" in g:
            del g[f"simplify/{name}"]
    g.create_array("simplify/keep_cells", shape=(total,), dtype="bool", chunks=(block,), fill_value=False, compressors=comp)
    g.create_array("simplify/done", shape=(n_cells,), dtype="uint8", chunks=(1,), fill_value=0, compressors=comp)
    g.create_array("simplify/score_cells", shape=(total,), dtype="float64", chunks=(block,), fill_value=0.0, compressors=comp)
    g.create_array("simplify/label_cells", shape=(total,), dtype="int32", chunks=(block,), fill_value=0, compressors=comp)
    g.create_array("simplify/scored", shape=(n_cells,), dtype="uint8", chunks=(1,), fill_value=0, compressors=comp)
    # start of each cell's region, read by the merge tasks (P numbers: not passed to every task)
    g.create_array("simplify/regions", data=np.asarray(regions, dtype=np.int64),
                   chunks=(max(1, min(len(regions), 65536)),), compressors=comp)


def _cell_args(st, part, regions, cells, params, threads: int = 1):
    """Arguments of the cell tasks (small, independent of P: the task reads its runs from the store).

    ``(path, cell, {halo source: region}, {cell and halo sources: centre}, margin, region, params)``;
    *params* gets the tasks' k-d tree thread count under "threads" (not part
    of the parameters recorded for resume: the results do not depend on it).
    """
    c = part.centers
    params = {**params, "threads": int(threads)}
    out = []
    for j in cells:
        j = int(j)
        halo = {int(s): int(regions[s]) for s in part.halo_sources(j)} if params["context"] else {}
        centers = {j: c[j], **{s: c[s] for s in halo}}
        out.append((st.path, j, halo, centers, part.margin, int(regions[j]), params))
    return out


def _largest_first(part, cells) -> list[int]:
    """*cells* by decreasing point count (ties by id): the longest tasks start first, so the
    stage does not end with one worker busy on a large cell while the others wait."""
    cells = np.asarray(cells, dtype=np.int64)
    return [int(j) for j in cells[np.lexsort((cells, -part.cell_counts[cells]))]] if len(cells) else []


def _run_cells(st, part, regions, params, runner, target, update):
    """Run the cell tasks still missing; returns (computed, reused, global threshold or None)."""
    g = st.group
    p = part.n_cells
    done = np.asarray(g["simplify/done"][:]).astype(bool)
    reused = int(done.sum())
    if target is None:
        todo = _largest_first(part, [j for j in range(p) if not done[j]])
        results = runner(cell_task, _cell_args(st, part, regions, todo, params, runner.task_threads), "cells")
        update(int(sum(r["n"] for r in results)))
        return len(todo), reused, None
    # ratio / count: pass 1 scores, one global threshold, pass 2 applies it
    scored = np.asarray(g["simplify/scored"][:]).astype(bool)
    todo = _largest_first(part, [j for j in range(p) if not scored[j] and not done[j]])
    results = runner(score_task, _cell_args(st, part, regions, todo, params, runner.task_threads), "cells: score")
    update(int(sum(r["n"] for r in results)))
    threshold = _global_threshold(st, part, regions, runner, st.count - target)
    todo2 = _largest_first(part, [j for j in range(p) if not done[j]])
    args = [a + (threshold,) for a in _cell_args(st, part, regions, todo2, params, runner.task_threads)]
    runner(apply_task, args, "cells: apply")
    return len(todo2), reused, threshold


def _global_threshold(st, part, regions, runner, remove: int) -> float:
    """The global threshold T on the stored unit-free scores: *remove* points have score <= T.

    Summed histograms of log10(score) (one small task per cell) narrow the
    range that holds the remove-th smallest score until it holds few points;
    those scores are then gathered and T is picked exactly among them with
    :func:`cloudsieve.prune.threshold_for_count`. Exact up to ties (equal
    scores go together). Every sum is over integers: the result does not
    depend on the task order.
    """
    from ..core.prune import threshold_for_count

    counts = part.cell_counts
    cells = [j for j in range(part.n_cells) if counts[j] > 0]
    total = int(counts.sum())
    if remove <= 0:
        return -math.inf
    if remove >= total:
        return math.inf
    lo, hi, bins = _HIST_LO, _HIST_HI, _HIST_BINS
    for _ in range(6):
        hists = runner(
            _score_hist_task, [(st.path, int(regions[j]), int(counts[j]), lo, hi, bins) for j in cells], "cells: threshold"
        )
        h = np.sum(np.stack(hists), axis=0)
        cum = np.cumsum(h)  # cum[0]: all scores below lo
        b = int(np.searchsorted(cum, remove, side="left"))
        if b == 0:  # among the scores below the range (zeros: duplicates): all go together
            return 10.0**lo if lo > _HIST_LO else 0.0
        if b >= bins + 1:  # among the scores above the range (+inf: always kept)
            return math.inf
        width = (hi - lo) / bins
        edge_lo, edge_hi = lo + (b - 1) * width, lo + b * width
        below = int(cum[b - 1])
        if h[b] <= _GATHER_MAX or width < 1e-9:
            parts = runner(
                _scores_between_task,
                [(st.path, int(regions[j]), int(counts[j]), edge_lo, edge_hi) for j in cells],
                "cells: threshold",
            )
            inside = np.concatenate(parts) if parts else np.empty(0)
            return float(threshold_for_count(inside, remove - below))
        lo, hi = edge_lo, edge_hi
    return 10.0**hi
