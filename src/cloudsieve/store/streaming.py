"""Helpers of the streaming stages (ingest, export), the store's reads and writes and the local workers:
a read-ahead thread, zarr calls in one event-loop call, a bounded heap."""

from __future__ import annotations

import logging
import os
import queue
import sys
import threading

__all__ = ["prefetch", "gathered", "bound_malloc", "in_process", "run_tasks"]

logger = logging.getLogger(__name__)


_MALLOC_TUNED = False


#: glibc's mmap threshold, fixed (bytes): buffers above it are mapped, and unmapped on free
MMAP_THRESHOLD = 16 << 20
#: glibc's trim threshold, fixed (bytes): up to this much free memory at the top of a heap stays mapped
TRIM_THRESHOLD = 256 << 20


def bound_malloc(threshold: int = MMAP_THRESHOLD, trim: int = TRIM_THRESHOLD) -> None:
    """Fix glibc's mmap and trim thresholds (``mallopt``), so memory stays flat in N and is reused.

    glibc's default mmap threshold rises with the largest buffer freed, after
    which chunk-sized buffers (megabytes) come from per-thread heaps that
    fragment: an ingest's peak RSS grows with N before levelling off, and the
    local workers (which free the label tasks' large arrays) grow the
    process tree's by half. A fixed mmap threshold of 16 MiB keeps it flat.
    With it, glibc's default trim threshold (128 KiB) gives each task's and
    each chunk's buffers back to the OS, and the next one faults them in
    again; a trim threshold of 256 MiB, in the workers and the driver, cuts
    a run's page faults by more than half for a little more peak RSS, still
    flat from 10 M to 50 M points. Process-wide,
    set once; each threshold is skipped when the user set its environment
    variable (MALLOC_MMAP_THRESHOLD_, MALLOC_TRIM_THRESHOLD_), and both when
    the C library is not glibc.
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
    """The results of zarr's coroutines *calls* (``Array.async_array`` reads and writes), in order, run
    concurrently in one call of zarr's event loop.

    Each call of zarr's event loop has an overhead of its own, whatever its
    size (a cell's ten runs, a task's five small writes), and the codecs
    release the GIL: a store chunk's arrays read together decode at once.
    """
    import asyncio  # here, as zarr: a run without a store (engine.small) imports neither

    from zarr.core.sync import sync

    calls = list(calls)
    if not calls:
        return []

    async def run_all() -> list:
        return await asyncio.gather(*calls)

    return sync(run_all())


def prefetch(chunks, depth: int = 1):
    """Iterate *chunks* produced by a background thread, *depth* chunks ahead.

    The producer's work overlaps with the consumer's where one of them
    releases the GIL (ingest: decoding the next chunk with compressing and
    writing the previous one, in the codecs' threads; export: reading and
    selecting a chunk with encoding the previous one). lazrs holds the GIL
    while it decodes or encodes: a Python thread that counts ran at 5-7% of
    its rate during a 1 M-point decode. Memory grows by *depth* chunks at
    most. Close the generator to stop the thread early.
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

    In this process, one after the other, when *run* is None, or when there
    is a single task and no dask.distributed cluster: a local worker process
    would only add its start-up (the fork server's imports and kernels) to that task.
    """
    if _direct(run, len(args)):
        return [func(*a) for a in args]
    return run(func, args, stage)
