"""Progress reporting: library code takes a callback, the CLI shows a bar or a log line.

Library functions take ``progress(n)`` (points or tasks just finished) or
``bars`` (one :func:`bar` per stage) and never print. :func:`bar` shows a
tqdm bar on stderr in a terminal (redrawn every second), else one INFO line
per stage on ``cloudsieve.progress`` when it ends::

    INFO cloudsieve.progress: cells: 12 tasks in 3.4 s
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator

logger = logging.getLogger(__name__)

#: seconds between redraws of a terminal bar (its elapsed time moves between updates)
REDRAW_SECONDS = 1.0
#: the words of the units in the log lines: (one, several)
_UNITS = {"pt": ("point", "points"), "task": ("task", "tasks"), "tile": ("tile", "tiles"),
          "method": ("method", "methods")}

ProgressCallback = Callable[[int], None]


def _noop(n: int) -> None:
    pass


def callback(progress: ProgressCallback | None) -> ProgressCallback:
    """Return *progress*, or a no-op when it is None."""
    return progress if progress is not None else _noop


@contextlib.contextmanager
def stage_bar(bars, stage: str, total: int | None, unit: str) -> Iterator[ProgressCallback]:
    """``bars(stage, total, unit)`` as a context yielding ``update(n)``, or a no-op when *bars* is None."""
    if bars is None:
        yield callback(None)
    else:
        with bars(stage, total, unit) as upd:
            yield callback(upd)


def both(*progress: ProgressCallback | None) -> ProgressCallback:
    """One callback calling each of the given ones (None ignored)."""
    calls = [p for p in progress if p is not None]

    def update(n: int) -> None:
        for p in calls:
            p(n)

    return update


@contextlib.contextmanager
def stage_line(desc: str, unit: str = "pt") -> Iterator[ProgressCallback]:
    """Count a stage's updates; when it ends (without an error) log one INFO line with the count and seconds."""
    done = [0]

    def update(n: int) -> None:
        done[0] += int(n)

    t0 = time.perf_counter()
    yield update
    word = _UNITS.get(unit, (unit, unit))[done[0] != 1]
    logger.info("%s: %s %s in %.1f s", desc, f"{done[0]:,}", word, time.perf_counter() - t0)


@contextlib.contextmanager
def _redrawn(t) -> Iterator[None]:
    """Redraw tqdm bar *t* every :data:`REDRAW_SECONDS` (elapsed time and rate) until the block ends."""
    stop = threading.Event()

    def loop() -> None:
        while not stop.wait(REDRAW_SECONDS):
            t.refresh()

    thread = threading.Thread(target=loop, name="cloudsieve-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


@contextlib.contextmanager
def bar(desc: str, total: int | None, unit: str = "pt", enabled: bool = True) -> Iterator[ProgressCallback]:
    """A stage's progress, yielded as an ``update(n)`` callback: a tqdm bar in a terminal (a counter when
    *total* is None), else one log line at its end (:func:`stage_line`); a no-op unless *enabled*."""
    if not enabled:
        yield _noop
        return
    if not sys.stderr.isatty():
        with stage_line(desc, unit) as update:
            yield update
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit=unit, unit_scale=True, file=sys.stderr, dynamic_ncols=True) as t:
        with _redrawn(t):
            yield t.update
