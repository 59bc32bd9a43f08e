"""A small input in memory: the eliminate rule without a work store, dask or zarr.

A LAS/LAZ/COPC or PLY cloud of at most :data:`IN_MEMORY_POINTS` points runs
the out-of-core steps on arrays in this process (:func:`cloudsieve.io.whole.read_whole`,
:mod:`.cell_scheme`, the export's writer) and writes the same bytes.
Nothing is left to resume: a rerun starts again.
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
#: at most this many input points run in memory (docs/benchmarks.md): the whole cloud is held, so the limit is
#: one of memory
IN_MEMORY_POINTS = 10_000_000


def fits_in_memory(sources: list[str], dst: str, opts: dict, points: int | None) -> bool:
    """Whether a run of *opts* on *sources* (*points* from their headers) needs no work store.

    True for the eliminate rule on LAS/LAZ/COPC files or one PLY file of 1 to
    :data:`IN_MEMORY_POINTS` points, written to LAS/LAZ/PLY/XYZ, with no store,
    resume or tiles (scheduler options: :func:`cloudsieve.engine.checks.check_run`)."""
    from ..core.rules import ELIMINATION, get
    from ..io import detect_format
    from ..io.las_plan import is_las_source

    return (points is not None and 0 < points <= IN_MEMORY_POINTS
            and get(opts["rule"]).engine == ELIMINATION
            and opts["store"] is None and not opts["resume"] and opts["tile_size"] is None
            and (is_las_source(sources) or (len(sources) == 1 and detect_format(sources[0]) == "ply"))
            and detect_format(dst, opts["format"]) in _WRITTEN)


def import_beside(points: int | None, cell_size: int) -> threading.Thread | None:
    """Start importing ``scipy.spatial`` on a thread while the cloud is read, if the partition needs it
    (more than one cell); returns the thread to join, or None."""
    from .sample import n_cells_for

    if points is None or n_cells_for(points, cell_size) <= 1 or "scipy.spatial" in sys.modules:
        return None
    thread = threading.Thread(target=_import_quietly, args=("scipy.spatial",), name="import scipy.spatial")
    thread.start()
    return thread


def _import_quietly(name: str) -> None:
    """Import *name*, leaving a failure to the import that needs it (:mod:`cloudsieve.lean_start` may
    hold a module back for a moment)."""
    try:
        importlib.import_module(name)
    except ImportError:
        pass


def run_small(sources: list[str], dst: str, opts: dict, summary: Summary, *, account: Callable[[Summary], None],
              progress: Callable[[int], None], bars=None, points: int | None = None) -> Summary:
    """Simplify the small cloud *sources* into *dst* in this process (:func:`fits_in_memory` said so).

    *opts*: the validated options; *summary* is filled in; *account*,
    *progress*, *bars* as in :class:`.outofcore.RunHooks`;
    *points*: the input's points from its headers.
    """
    from ..core._validation import ratio_count
    from ..io import detect_format, open_writer
    from ..io.whole import read_whole
    from .cell_scheme import eliminate_cells, partition
    from .class_policy import ClassPolicy, class_codes
    from .density import DensityTarget, area_counts, area_keys

    summary.scheduler = SCHEDULER
    proc = ahead.start(targets_of(opts["rule"]))  # a second core compiles ahead
    importing = import_beside(points, opts["cell_size"])
    try:
        with PeakMemory() as peak, small_pages():
            t0 = time.perf_counter()
            xyz, attrs, dtypes, header, bounds, source_format = read_whole(sources, opts["chunk_size"],
                                                                           opts["drop_invalid"])
            header = json.loads(json.dumps(header))  # as the store keeps it (JSON)
            n = summary.points_in = len(xyz)
            progress(n)
            summary.seconds["ingest"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            ratio, count = opts["ratio"], opts["count"]
            density = DensityTarget.from_options(opts)
            if density is None:
                target = ratio_count(ratio, n) if ratio is not None else min(int(count), n)
            else:  # r_max for all the points kept
                areas = area_keys(xyz, density.side, density.dims)
                before = area_counts(areas)
                target = density.target(before[1])
            policy = ClassPolicy.from_options(opts)
            if policy is not None:  # each group's target; r_max for all the points kept
                codes = class_codes(attrs["classification"], ", ".join(sources))
                classes = np.bincount(codes, minlength=256)
                target = policy.asked(classes)
            part, order = partition(xyz, bounds[0], opts, target)
            summary.cells = summary.cells_computed = part.n_cells
            logger.info("%d points in memory, %d cells: eliminate %d, r_max %.4g", n, part.n_cells, target,
                        part.r_max)
            summary.seconds["partition"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            if policy is None:
                keep, distinct, summary.gap = eliminate_cells(xyz, part, order, target, opts["keep_duplicates"],
                                                              max_gap=opts.get("max_gap"), density=density)
                if density is not None:
                    summary.density = density.report(before, area_counts(areas[keep]))
            else:
                keep, distinct, summary.gap = eliminate_cells(xyz, part, order, policy.targets(classes),
                                                              opts["keep_duplicates"], policy=(codes, policy),
                                                              max_gap=opts.get("max_gap"))
                summary.classes = policy.report(classes, np.bincount(codes[keep], minlength=256))
            summary.duplicates = n - distinct
            summary.kept = int(keep.sum())
            summary.removed = n - summary.kept
            progress(n)
            summary.seconds["cells"] = time.perf_counter() - t0
            summary.seconds["merge"] = 0.0  # eliminate_cells gives input order
            account(summary)

            t0 = time.perf_counter()
            fmt = detect_format(dst, opts["format"])
            rows = np.flatnonzero(keep)
            dtypes = {name: (np.dtype(dt), tuple(shape)) for name, (dt, shape) in dtypes.items()}
            dtypes["xyz"] = (np.dtype(np.float64), (3,))
            step = opts["chunk_size"]
            ends = np.searchsorted(rows, np.arange(step, n + step, step))  # the kept rows of each store chunk
            with stage_bar(bars, "export", len(rows), "pt") as bar:
                # the export's writer and arguments (store/export.py)
                label = {"label": dst} if fmt in ("las", "laz") else {}
                with open_writer(dst, header=header, dtypes=dtypes, format=opts["format"], source_format=source_format,
                                 overwrite=opts["overwrite"], bounds=bounds, **label) as writer:
                    for a, b in zip(np.r_[0, ends[:-1]], ends):  # chunk by chunk, as the export
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
