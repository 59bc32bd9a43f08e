"""Out-of-core, distributed simplification: :func:`simplify`, the whole pipeline as dask tasks.

The stages (ingest, partition, cells, merge, export) are in their own
modules (docs/architecture.md); a small input runs them in memory
(:mod:`.small`). Tasks exchange only a few numbers, never an array of size
P or N. Results do not depend on the scheduler, worker count or completion
order: cells keep input order, seeds are ``SeedSequence([seed, cell])``,
reductions are over integers or in a fixed order.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence

from ..core.rules import ELIMINATION
from ..core.rules import get as get_rule
from ..errors import TargetNotMetError
from ..io.sources import remembered
from ..params import given, run_record, validate
from ..progress import callback
from ..rule_table import targets_of
from ..store import DEFAULT_CHUNK_SIZE
from .. import storage, storage_retries
from .checks import check_run
from .levels import listed, run_levels
from .summary import Summary, missed_target
from .workstore import ENGINE_VERSION

__all__ = ["simplify", "run_simplify", "Summary"]

logger = logging.getLogger(__name__)


def simplify(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    method: str = "km",
    rule: str | None = None,
    threshold: float | None = None,
    ratio: float | Sequence[float] | None = None,
    count: int | Sequence[int] | None = None,
    keep_class=None,
    class_ratio=None,
    density: float | None = None,
    density_cell: float | None = None,
    density_3d: bool = False,
    cluster_size: int = 400,
    cell_size: int = 200_000,
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
    halo_context: bool = False,
    k0: float = 1.0,
    k_min: int = 4,
    drop_invalid: bool = False,
    keep_duplicates: bool = False,
    exact: bool = False,
    tile_size: float | None = None,
    rank: bool = False,
    storage_options: dict | None = None,
    max_gap: float | None = None,
) -> Summary:
    """Simplify a point cloud of any size, out of core, on dask.

    Every option (:mod:`cloudsieve.params`), the source, the destination and
    the scheduler are checked before any file or store is created.

    Parameters
    ----------
    src : str or path-like
        Input file (any format :mod:`cloudsieve.io` reads), a point store, or
        LAS/LAZ/COPC files as one cloud: a glob, a directory, a list file or
        a VPC (:mod:`cloudsieve.io.sources`).
    dst : str or path-like
        Output file (any format :mod:`cloudsieve.io` writes), written atomically.
    method : {"km", "fcm"}
        Refinement into small clusters: K-means (default) or fuzzy C-means.
    rule : str, optional
        Pruning rule of :data:`cloudsieve.core.rules.RULES`. ``eliminate``
        (:mod:`cloudsieve.engine.eliminate`) keeps exactly the requested count
        and ignores ``method``, ``cluster_size`` and ``halo_context``. Default:
        ``eliminate`` with *ratio* or *count*, ``threshold`` with only
        *threshold*; none of the three is an InvalidParameterError.
    threshold : float, optional
        S, the entropy-change threshold of the threshold/iterative rules (default 1e-3).
    ratio, count : float in (0, 1] or int >= 1, or a list of them, optional
        Keep this share / number of the input points instead of using S;
        the total lands within 1% of it (exactly with eliminate). With
        *keep_class* or *class_ratio*, of the points not kept whole and not
        in *class_ratio*. A list (rule eliminate) writes nested outputs, one
        per value, each a subset of the one before (:mod:`cloudsieve.engine.levels`):
        DST's ``{ratio}`` or ``{count}`` replaced by the value, else ``DST-0.5.laz``....
    keep_class : str or list of int, optional
        LAS classes kept whole ("2,9" or ``[2, 9]``), exact records; they
        stay context for the others' crowding (rule eliminate only).
    class_ratio : str or dict, optional
        A ratio per LAS class ("5=0.1,2=1.0" or ``{5: 0.1}``; 1.0 keeps it
        whole), each class's count exact (rule eliminate only). The summary's
        ``classes`` states per class the points in and kept.
    density, density_cell : float, optional
        Instead of *ratio*/*count* (rule eliminate only): at most *density*
        points per square unit of the horizontal plane in every square area
        of side *density_cell* (default 10; a grid anchored at 0). An area
        holding more than floor(D R^2) points keeps exactly that many, the
        others keep all theirs. The summary's ``density`` states the points
        per square unit of the areas before and after.
    density_3d : bool
        *density* per cubic unit in cubes of side *density_cell* (objects):
        floor(D R^3) points per cube.
    cluster_size : int
        Points per small cluster (c = ceil(n / cluster_size) per cell), >= ``k_min + 2``.
    cell_size : int
        Points per coarse cell, i.e. per task; bounds a task's memory (about
        2 kB per point; docs/benchmarks.md, "Out of core on dask").
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
        Continue the run recorded in the work store (a rerun with the same store does so anyway).
    client : distributed.Client, optional
        Run on this cluster (workers must reach the store path).
    overwrite : bool
        Overwrite DST, and discard a work store left by another run.
    progress, bars, notify : callable, optional
        ``progress(n)`` after n points of a stage; ``bars(stage, total,
        unit)`` -> context manager yielding ``update(n)``
        (:func:`cloudsieve.progress.bar`); ``notify(message)`` for what a
        user should see at once (the dashboard link).
    format : str, optional
        Output format (default: by DST's extension).
    chunk_size : int
        Points per chunk of the ingested store.
    halo_context : bool
        True: the cell and its halo (:func:`cloudsieve.engine.cells.thinned_halo`)
        are every cluster's density context; False (default): each small
        cluster alone (the paper).
    k0, k_min : float, int
        The k-NN rule k = max(k_min, round(k0 * sqrt(m))).
    drop_invalid : bool
        Drop (and log) points of a file SRC with NaN or infinite coordinates.
    keep_duplicates : bool
        Keep every exact copy (same x, y, z) of a kept point; by default
        duplicates are scored and kept once (:attr:`Summary.duplicates`).
    exact : bool
        Raise instead of logging when a ratio or count is not met exactly.
    tile_size : float, optional
        Write DST as a folder of square LAZ tiles plus ``DST/index.vpc``
        (:func:`cloudsieve.store.tiles.export_tiles`).
    rank : bool
        Store each point's rank in the extra dimension ``cloudsieve_rank``
        (:mod:`cloudsieve.io.rank`): the first N ranks are the points to keep at
        N, cut by ``cloudsieve export --keep-rank N``. Rule eliminate, LAS/LAZ/COPC out.
    storage_options : dict, optional
        fsspec options for every URL of the run (e.g. s3fs's ``key``,
        ``secret``, ``endpoint_url``); never logged, recorded or printed.
    max_gap : float, optional
        Gap bound D > 0 (CRS units, Euclidean 3D; rule ``eliminate`` only):
        after the elimination, points are added back until no input point is
        farther than D from the kept set, so the ratio or count becomes "at
        least" (:attr:`Summary.gap`: the points added, the largest gap
        checked exactly; :mod:`cloudsieve.engine.gap`).

    Returns
    -------
    Summary
        Also stored in the store's attributes under ``"cloudsieve_simplify"``.

    Raises
    ------
    InvalidParameterError
        An option out of its range, or options that contradict each other.
    InputNotFoundError, InputIsDirectoryError, UnknownFormatError, StoreNotFoundError
        SRC cannot be read.
    DestinationExistsError
        DST exists and *overwrite* is False.
    UnknownFormatError, DestinationNotWritableError
        DST's format cannot be written, or its folder is missing or not writable.
    SchedulerUnreachableError
        Nothing answers at the *scheduler* address (5 s connect timeout).
    ResumeMismatchError
        The work store holds a run with other parameters or another source.
    InvalidPointsError
        SRC has NaN or infinite coordinates and *drop_invalid* is False.
    TargetNotMetError
        *exact* and the kept count differs from the ratio or count asked
        (before DST is written).
    """
    t_start = time.perf_counter()
    opts = validate("simplify", given("simplify", locals()))
    return run_simplify(src, dst, opts, client=client, progress=progress, bars=bars, notify=notify, t_start=t_start)


def run_simplify(src: str | os.PathLike, dst: str | os.PathLike, opts: dict, *, client=None, progress=None, bars=None,
                 notify=None, t_start: float | None = None) -> Summary:
    """:func:`simplify` with ``opts`` already validated by :func:`cloudsieve.params.validate`."""
    if listed(opts) or opts.get("rank"):  # nested outputs, each run below on the one before
        def one(source: str, destination: str, level: dict) -> Summary:
            return run_simplify(source, destination, level, client=client, progress=progress, bars=bars,
                                notify=notify)

        return run_levels(os.fspath(src), os.fspath(dst), opts, one)
    # every URL of the run, here and in its tasks; SRC listed once
    with storage.using(opts.get("storage_options")), remembered():
        return _run_simplify(src, dst, opts, client=client, progress=progress, bars=bars, notify=notify,
                             t_start=t_start)


def _run_simplify(src, dst, opts: dict, *, client, progress, bars, notify, t_start) -> Summary:
    t_start, src, dst = time.perf_counter() if t_start is None else t_start, os.fspath(src), os.fspath(dst)
    ratio, count, keep_duplicates, exact, tile_size = (
        opts[name] for name in ("ratio", "count", "keep_duplicates", "exact", "tile_size"))
    if tile_size is not None and len(dst) > 1:
        dst = dst.rstrip("/")  # a folder given as "out/": the work store goes beside it, not inside
    params = {"version": ENGINE_VERSION, **run_record(opts)}
    rule = opts["rule"]  # resolved: None -> eliminate (a ratio or count) or threshold (a threshold alone)
    update, cpu0 = callback(progress), (time.process_time(), storage_retries.counts())
    summary = Summary(source=src, destination=dst, duplicates_kept=keep_duplicates)
    checked = check_run(src, dst, opts, params, client=client)

    def account(summary: Summary) -> None:  # the kept count known, DST not yet written
        if summary.duplicates:
            logger.info("%d exact duplicates %s", summary.duplicates,
                        "kept (keep_duplicates)" if keep_duplicates else "removed")
        filled = summary.gap["filled"] if summary.gap is not None else 0  # the gap bound's: "at least"
        missed = missed_target(src, ratio, count, summary.points_in, summary.kept - filled, summary.duplicates,
                               keep_duplicates, exact=get_rule(rule).engine == ELIMINATION,
                               asked=summary.classes["asked"] if summary.classes else None)
        if missed and exact:
            raise TargetNotMetError(missed)
        if missed:
            logger.warning("%s", missed)

    if checked.in_memory:  # a small input: no work store, no dask
        from .small import run_small

        run_small(checked.sources, dst, opts, summary, account=account, progress=update, bars=bars,
                  points=checked.points)
        return _finished(summary, t_start, cpu0)
    if client is None:  # the local workers start while the stages import
        from .runner import boot

        boot(checked.scheduler, opts["memory_limit"], targets_of(rule))
    from .outofcore import RunHooks, run_store  # the work store, dask and the stages: only for a run that needs them

    hooks = RunHooks(account=account, progress=update, finished=lambda s: _finished(s, t_start, cpu0), bars=bars,
                     notify=notify)
    return run_store(checked, src, dst, opts, params, summary, hooks, client=client)


def _finished(summary: Summary, t_start: float, cpu0: tuple) -> Summary:
    """*summary* with total time, driver CPU and object-store retries added, logged.

    *cpu0*: ``(CPU time, storage_retries.counts())`` at the start."""
    summary.seconds["total"] = time.perf_counter() - t_start
    summary.cpu_seconds["driver"] = time.process_time() - cpu0[0]
    (uses0, retries0), (uses, retries) = cpu0[1], storage_retries.counts()
    workers = (summary.storage or {}).get("retries", 0)
    summary.storage = {"retries": workers + retries - retries0} if uses > uses0 else None
    logger.info("simplify %s -> %s: %d of %d points kept", summary.source, summary.destination, summary.kept,
                summary.points_in)
    return summary
