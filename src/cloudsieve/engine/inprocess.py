"""Small inputs run in the calling process: no process pool, no fork server.

A cloud of at most :data:`IN_PROCESS_POINTS` points is one cell at the
default ``cell_size`` (200,000): one cell task, nothing for worker processes to
share, and starting them (a fork server that imports the engine and loads the
kernels, then the workers) cost more than the whole run. Measured on 2 cores,
the whole ``cloudsieve simplify SRC DST --ratio 0.5`` (warm numba cache,
side by side, load 7.1-7.8): autzen_trim.laz (110,000 points) 6.61-6.75 s
with the process pool, 3.67-5.65 s in process; simple.las (1,065 points)
6.57-7.63 s and 3.34-3.82 s. The tasks are the same and run in the same order on dask's
synchronous scheduler (:class:`~.runner.Runner` "sync"), so the output is the
same, byte for byte (tests/test_speed_start.py), and a cell's k-NN and kernels
use every core.

Only when the caller chose nothing: no scheduler, no client, no memory limit, no worker count.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

__all__ = ["IN_PROCESS_POINTS", "source_points", "local_scheduler"]

logger = logging.getLogger(__name__)

#: at most this many input points run in the calling process (the default cell size: one cell)
IN_PROCESS_POINTS = 200_000
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
    n = source_points(sources, store)
    if n is not None and n <= limit:
        logger.info("%d points: run in this process (at most %d)", n, limit)
        return "sync"
    return None
