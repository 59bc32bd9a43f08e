"""Small inputs run in the calling process, on dask's "sync" scheduler: no process pool, no fork server.

Up to :data:`IN_PROCESS_POINTS` points, starting the pool costs more than
its workers gain and doubles the peak memory (docs/benchmarks.md, "Small
inputs"); the tasks and their order are the same, so is the output. Only
when the caller chose no scheduler, client, memory limit or worker count.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

__all__ = ["IN_PROCESS_POINTS", "source_points", "local_scheduler", "scheduler_for"]

logger = logging.getLogger(__name__)

#: at most this many input points run in the calling process
IN_PROCESS_POINTS = 1_500_000
#: the formats whose count is read from the header, silently
_HEADER_COUNTS = ("las", "laz", "copc", "ply")


def source_points(sources: Sequence[str], store: str | None = None) -> int | None:
    """The points of *sources* (files) or of the point *store*, from their headers; None when a format does
    not say (XYZ), may log at opening (E57), or a source cannot be opened (the run reports it)."""
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
    except Exception:  # noqa: BLE001 - only a choice of scheduler
        return None


def local_scheduler(sources: Sequence[str], store: str | None = None, *,
                    limit: int = IN_PROCESS_POINTS) -> str | None:
    """``"sync"`` (this process) when the input (files or a *store*) has at most *limit* points, else None."""
    return scheduler_for(source_points(sources, store), limit=limit)


def scheduler_for(points: int | None, *, limit: int = IN_PROCESS_POINTS) -> str | None:
    """:func:`local_scheduler` of an input of *points* points (:func:`source_points`)."""
    if points is not None and points <= limit:
        logger.info("%d points: run in this process (at most %d)", points, limit)
        return "sync"
    return None
