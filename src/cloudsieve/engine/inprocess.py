"""Small inputs run in the calling process: no process pool, no fork server.

Up to :data:`IN_PROCESS_POINTS` points the run's tasks run one after the
other in this process, on dask's synchronous scheduler (:class:`~.runner.Runner`
"sync"), each cell's kernels on every core: starting the local process pool (a
fork server that imports the engine and loads the kernels, then the workers)
costs more than two workers gain up to about 1.5 M points, and the pool
doubles the peak memory (docs/benchmarks.md, "Small inputs"). The tasks are
the same and run in the same order, so the output is the same, byte for
byte (tests/test_speed_start.py); its LAZ is decoded on every core.

Only when the caller chose nothing: no scheduler, no client, no memory limit, no worker count.
A LAS/LAZ/COPC or PLY input of the eliminate rule needs no work store either (:mod:`.small`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

__all__ = ["IN_PROCESS_POINTS", "source_points", "local_scheduler", "scheduler_for"]

logger = logging.getLogger(__name__)

#: at most this many input points run in the calling process (module docstring: the process pool is no faster
#: below about 2 M points on 2 cores)
IN_PROCESS_POINTS = 1_500_000
#: the formats whose count is read from the header, silently
_HEADER_COUNTS = ("las", "laz", "copc", "ply")


def source_points(sources: Sequence[str], store: str | None = None) -> int | None:
    """The points of *sources* (files) or of the point *store*, from their headers; None when a format
    does not say (XYZ text), its reader may log at opening (E57: the fields it skips, which the ingest
    logs once), or a source cannot be opened (the run then reports it)."""
    try:
        if store is not None:
            from ..store import PointStore

            return int(PointStore.open(store).count)
        from ..io import detect_format, open_reader

        total = 0
        for path in sources:
            if detect_format(path) not in _HEADER_COUNTS:
                return None
            with open_reader(path) as reader:
                if reader.count is None:
                    return None
                total += int(reader.count)
        return total
    except Exception:  # noqa: BLE001 - only a choice of scheduler: the run itself reports what is wrong
        return None


def local_scheduler(sources: Sequence[str], store: str | None = None, *,
                    limit: int = IN_PROCESS_POINTS) -> str | None:
    """``"sync"`` (the calling process) when the input has at most *limit* points, else None (the default
    local process pool).

    Parameters
    ----------
    sources : sequence of str
        The input files (:func:`cloudsieve.io.sources.expand_sources`).
    store : str, optional
        The input point store, instead of files.
    limit : int
        The largest input run in the calling process.
    """
    return scheduler_for(source_points(sources, store), limit=limit)


def scheduler_for(points: int | None, *, limit: int = IN_PROCESS_POINTS) -> str | None:
    """:func:`local_scheduler` of an input of *points* points (:func:`source_points`)."""
    if points is not None and points <= limit:
        logger.info("%d points: run in this process (at most %d)", points, limit)
        return "sync"
    return None
