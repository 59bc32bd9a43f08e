"""A small input in memory: the eliminate rule without a work store, dask or zarr.

A LAS/LAZ/COPC or PLY cloud of at most :data:`IN_MEMORY_POINTS` points runs
the out-of-core run's steps on the same arrays, in this process, and writes
the same bytes (tests/test_engine_small.py):

1. the cloud read whole by :func:`cloudsieve.io.whole.read_whole`: the
   records as an ingest task reads them, x, y, z decoded as the store
   decodes them; a PLY file as the ingest streams it (NaN or infinite
   coordinates refused, or dropped with ``drop_invalid``);
2. the partition and the cells stage on arrays (:mod:`.cell_scheme`): r_max
   from the partition's uniform sample, the cells and their halos, each
   cell's count and its elimination colour by colour
   (:func:`~cloudsieve.core.eliminate_cells.eliminate_cell`), every copy
   of a kept point kept with ``keep_duplicates``;
3. the kept points written by the export's writer
   (:func:`cloudsieve.io.open_writer`) with the store's header, dtypes and
   bounds, store chunk by store chunk (atomic: a temporary name, renamed
   when complete).

A store costs a small run more than its points do: hundreds of synchronous
calls of zarr's event loop, dask's local scheduler, and importing both
(docs/benchmarks.md). Nothing is left to resume: a crash leaves no partial
output, and a rerun starts again.
"""

from __future__ import annotations

import importlib
import json
import logging
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from . import ahead
from ..rule_table import targets_of
from ..progress import stage_bar
from .memory import PeakMemory, small_pages
from .summary import Summary

__all__ = ["fits_in_memory", "import_beside", "run_small", "SCHEDULER"]

logger = logging.getLogger(__name__)

#: the scheduler a small run reports (no dask scheduler runs)
SCHEDULER = "in memory"
#: the output formats a small run writes (COPC and tiles are built from a store)
_WRITTEN = ("las", "laz", "ply", "xyz")
#: at most this many input points run in memory (docs/benchmarks.md, benchmarks/small.py): faster than the local
#: process pool at every size and, up to 10 M points, in less memory: the whole cloud is held (about 0.1 GB a
#: million points above the kernels' 0.3 GB), where the out-of-core run holds cells only, so the limit is one of
#: memory
IN_MEMORY_POINTS = 10_000_000


def fits_in_memory(sources: list[str], dst: str, opts: dict, points: int | None) -> bool:
    """Whether a run of the validated *opts* on *sources* (*points* in their headers) needs no work store:
    the eliminate rule on LAS/LAZ/COPC files or one PLY file of 1 to :data:`IN_MEMORY_POINTS` points,
    written to LAS/LAZ/PLY/XYZ; no named store, no resume, no tiles; the caller chose no scheduler,
    client, workers or memory limit (checked by :func:`cloudsieve.engine.checks.check_run`)."""
    from ..core.rules import ELIMINATION, get
    from ..io import detect_format
    from ..io.las_plan import is_las_source

    return (points is not None and 0 < points <= IN_MEMORY_POINTS
            and get(opts["rule"]).engine == ELIMINATION
            and opts["store"] is None and not opts["resume"] and opts["tile_size"] is None
            and (is_las_source(sources) or (len(sources) == 1 and detect_format(sources[0]) == "ply"))
            and detect_format(dst, opts["format"]) in _WRITTEN)


def import_beside(points: int | None, cell_size: int) -> threading.Thread | None:
    """Start importing ``scipy.spatial`` on a thread while the cloud is read, when the partition will need it:
    an input of *points* (from its headers) in more than one cell of *cell_size* points. Returns the thread
    (join it before the run returns), or None.

    The partition's margin and its K-means centres query scipy's cKDTree, and would wait for its import; a
    PLY's read leaves the second core idle and laspy's LAZ decode lets the import go on beside it (docs/
    benchmarks.md; the same bytes). A one-cell run never imports scipy."""
    from .sample import n_cells_for

    if points is None or n_cells_for(points, cell_size) <= 1 or "scipy.spatial" in sys.modules:
        return None
    thread = threading.Thread(target=_import_quietly, args=("scipy.spatial",), name="import scipy.spatial")
    thread.start()
    return thread


def _import_quietly(name: str) -> None:
    """Import *name*; a failure is left to the import that needs it (the partition's, which reports it): an
    import may fail here only while :mod:`cloudsieve.lean_start` holds back one of its modules for a moment
    (``scipy.linalg.cython_blas``, while numba's first compile imports ``numba.np.arraymath``)."""
    try:
        importlib.import_module(name)
    except ImportError:
        pass


def run_small(sources: list[str], dst: str, opts: dict, summary: Summary, *, account: Callable[[Summary], None],
              progress: Callable[[int], None], bars=None, points: int | None = None) -> Summary:
    """Simplify the small cloud *sources* into *dst* in this process (:func:`fits_in_memory` said so).

    Parameters
    ----------
    sources : list of str
        The input files (one cloud).
    dst : str
    opts : dict
        The validated options of :func:`cloudsieve.engine.simplify`.
    summary : Summary
        Filled in: counts, seconds, memory, scheduler (:data:`SCHEDULER`).
    account : callable
        ``account(summary)`` once the kept count is known, before DST is written: logs the duplicates and
        a missed target, or raises :class:`~cloudsieve.errors.TargetNotMetError` (strict).
    progress : callable
        ``progress(n)`` after each stage (n points).
    bars : callable, optional
        As for :func:`cloudsieve.engine.simplify`.
    points : int, optional
        The input's points from its headers (:func:`import_beside`).
    """
    from ..core._validation import ratio_count
    from ..io import detect_format, open_writer
    from ..io.whole import read_whole
    from .cell_scheme import eliminate_cells, partition

    summary.scheduler = SCHEDULER
    proc = ahead.start(targets_of(opts["rule"]))  # into an empty numba cache: a second core compiles ahead
    importing = import_beside(points, opts["cell_size"])
    try:
        with PeakMemory() as peak, small_pages():
            t0 = time.perf_counter()
            xyz, attrs, dtypes, header, bounds, source_format = read_whole(sources, opts["chunk_size"],
                                                                           opts["drop_invalid"])
            header = json.loads(json.dumps(header))  # as the store keeps it: JSON (lists, not tuples)
            n = summary.points_in = len(xyz)
            progress(n)
            summary.seconds["ingest"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            ratio, count = opts["ratio"], opts["count"]
            target = ratio_count(ratio, n) if ratio is not None else min(int(count), n)
            part, order = partition(xyz, bounds[0], opts, target)
            summary.cells = summary.cells_computed = part.n_cells
            logger.info("%d points in memory, %d cells: eliminate %d, r_max %.4g", n, part.n_cells, target,
                        part.r_max)
            summary.seconds["partition"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            keep, distinct = eliminate_cells(xyz, part, order, target, opts["keep_duplicates"])
            summary.duplicates = n - distinct
            summary.kept = int(keep.sum())
            summary.removed = n - summary.kept
            progress(n)
            summary.seconds["cells"] = time.perf_counter() - t0
            summary.seconds["merge"] = 0.0  # in the cells stage: eliminate_cells puts the mask in input order
            account(summary)

            t0 = time.perf_counter()
            fmt = detect_format(dst, opts["format"])
            rows = np.flatnonzero(keep)
            dtypes = {name: (np.dtype(dt), tuple(shape)) for name, (dt, shape) in dtypes.items()}
            dtypes["xyz"] = (np.dtype(np.float64), (3,))
            step = opts["chunk_size"]
            ends = np.searchsorted(rows, np.arange(step, n + step, step))  # the kept rows of each store chunk
            with stage_bar(bars, "export", len(rows), "pt") as bar:
                # the export's writer and arguments (store/export.py; a LAS part names the whole file)
                label = {"label": dst} if fmt in ("las", "laz") else {}
                with open_writer(dst, header=header, dtypes=dtypes, format=opts["format"], source_format=source_format,
                                 overwrite=opts["overwrite"], bounds=bounds, **label) as writer:
                    for a, b in zip(np.r_[0, ends[:-1]], ends):  # as the export reads the store: chunk by chunk
                        take = rows[a:b]
                        writer.write({name: (xyz if name == "xyz" else attrs[name]).take(take, axis=0)
                                      for name in dtypes})
                bar(len(rows))
            if not len(rows):
                logger.warning("%s: no point kept; wrote an empty cloud", dst)
            summary.seconds["export"] = time.perf_counter() - t0
    finally:
        ahead.finish(proc)
        if importing is not None:
            importing.join()
    summary.peak_memory, summary.peak_memory_of = int(peak.peak), peak.scope
    summary.store = ""
    return summary
