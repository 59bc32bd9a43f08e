"""Helpers of the streaming stages and store I/O: a read-ahead thread, batched zarr calls, a bounded heap."""

from __future__ import annotations

import logging
import os
import queue
import sys
import threading

__all__ = ["prefetch", "gathered", "bound_malloc", "in_process", "run_tasks"]

logger = logging.getLogger(__name__)
_MALLOC_TUNED = False


#: glibc's mmap threshold, fixed (bytes)
MMAP_THRESHOLD = 16 << 20
#: glibc's trim threshold, fixed (bytes): free memory kept mapped at a heap's top
TRIM_THRESHOLD = 256 << 20


def bound_malloc(threshold: int = MMAP_THRESHOLD, trim: int = TRIM_THRESHOLD) -> None:
    """Fix glibc's mmap and trim thresholds (``mallopt``), so memory stays flat in N and is reused.

    The default mmap threshold rises with the largest buffer freed, after
    which chunk-sized buffers fragment per-thread heaps; a large trim
    threshold keeps freed buffers mapped for the next task. Process-wide,
    once; a threshold whose variable (MALLOC_MMAP_THRESHOLD_,
    MALLOC_TRIM_THRESHOLD_) is set is skipped; nothing outside glibc.
    """
    global _MALLOC_TUNED
    if _MALLOC_TUNED or not sys.platform.startswith("linux"):
        return
    _MALLOC_TUNED = True
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        if "MALLOC_MMAP_THRESHOLD_" not in os.environ:
            libc.mallopt(-3, int(threshold))  # M_MMAP_THRESHOLD
        if "MALLOC_TRIM_THRESHOLD_" not in os.environ:
            libc.mallopt(-1, int(trim))  # M_TRIM_THRESHOLD
        logger.debug("glibc mmap threshold set to %d bytes, trim threshold to %d", threshold, trim)
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


def gathered(calls) -> list:
    """The results of zarr coroutines *calls* (``async_array`` reads and writes), in order, run concurrently
    in one event-loop call: each call has a fixed overhead, and the codecs release the GIL."""
    import asyncio  # here: a run without a store imports no zarr

    from zarr.core.sync import sync

    calls = list(calls)
    if not calls:
        return []

    async def run_all() -> list:
        return await asyncio.gather(*calls)

    return sync(run_all())


def prefetch(chunks, depth: int = 1):
    """Iterate *chunks* produced by a background thread, *depth* chunks ahead.

    Overlaps producer and consumer where either releases the GIL (lazrs does
    not). Memory grows by *depth* chunks at most. Close the generator to stop
    the thread early.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for chunk in chunks:
                if not put(("ok", chunk)):
                    return
            put(("ok", done))
        except BaseException as exc:  # handed to the consumer
            put(("error", exc))

    thread = threading.Thread(target=produce, name="cloudsieve-reader", daemon=True)
    thread.start()
    try:
        while True:
            kind, item = q.get()
            if kind == "error":
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            thread.join(timeout=0.05)


def _direct(run, n_tasks: int) -> bool:
    """Whether :func:`run_tasks` calls the *n_tasks* tasks itself, without *run*."""
    return run is None or (n_tasks <= 1 and getattr(run, "client", None) is None)


def in_process(run, n_tasks: int) -> bool:
    """Whether :func:`run_tasks` runs *n_tasks* tasks through *run* in this process, one after the other."""
    return _direct(run, n_tasks) or getattr(run, "local", None) == "sync"


def run_tasks(run, func, args: list, stage: str) -> list:
    """``[func(*a) for a in args]`` through *run* (a :class:`cloudsieve.engine.runner.Runner`), results in order.

    Runs here, in turn, when *run* is None or for a single task without a
    dask.distributed cluster (a worker would only add its start-up).
    """
    if _direct(run, len(args)):
        return [func(*a) for a in args]
    return run(func, args, stage)
