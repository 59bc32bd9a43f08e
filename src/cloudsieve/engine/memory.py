"""Peak memory of a run: this process and its children, or the workers of a dask cluster.

:class:`PeakMemory` samples in a thread. A local run (every scheduler that
starts its workers here, a LocalCluster included) measures the resident
memory of this process and all its children (read from /proc on Linux). A
run on a dask.distributed cluster whose workers live elsewhere
(``--scheduler tcp://...`` or a given client) measures the workers instead:
each worker reports its own resident memory (psutil, through
``client.run``), and the peak of their sum is reported, labelled with the
number of workers (:attr:`PeakMemory.scope`); the client's own memory is not
part of it.

:func:`small_pages` keeps numpy's large arrays off transparent huge pages
while a cloud is simplified in memory; :func:`small_pages_from_here` for
the rest of the process and every process it starts (the command).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import sys
import threading

__all__ = ["HUGEPAGE_ENV", "PeakMemory", "process_tree_rss", "small_pages", "small_pages_from_here",
           "worker_rss"]

logger = logging.getLogger(__name__)

#: what a local measure covers
LOCAL_SCOPE = "this process and its children"
#: how long stopping waits for a sample in flight (a worker's answer takes milliseconds)
JOIN_SECONDS = 60
#: numpy's own switch of its huge-page advice, read when numpy is imported
HUGEPAGE_ENV = "NUMPY_MADVISE_HUGEPAGE"


def set_huge_pages(on: bool) -> bool:
    """Tell numpy whether to advise huge pages for its large arrays; returns what it did before (False, and
    nothing changed, for a numpy without the switch: it is private)."""
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):  # numpy 2, numpy 1
        try:
            switch = importlib.import_module(module)._set_madvise_hugepage
        except (ImportError, AttributeError):
            continue
        return bool(switch(bool(on)))
    return False


@contextlib.contextmanager
def small_pages():
    """Inside, numpy's arrays of 4 MiB and more go on the kernel's 4 KiB pages; unless ``NUMPY_MADVISE_HUGEPAGE``
    is set, which is then obeyed.

    On Linux numpy advises transparent huge pages (``madvise``) for such
    arrays, and the kernel zeroes a whole 2 MiB page at its first touch. On
    a virtual machine that zeroing is slow: it is most of the system time of
    a 10 M-point simplify in memory, which 4 KiB pages save, the same bytes
    out (docs/architecture.md, "Design reasons").
    The switch is numpy's, for the whole process: it is restored on leaving.
    """
    if HUGEPAGE_ENV in os.environ:
        yield
        return
    was = set_huge_pages(False)
    try:
        yield
    finally:
        set_huge_pages(was)



def small_pages_from_here() -> None:
    """:func:`small_pages` for the rest of this process and every process started from it, unless
    ``NUMPY_MADVISE_HUGEPAGE`` is set: the variable set to 0, which numpy reads at its import (the fork
    server, the workers), and numpy told at once if already imported."""
    if HUGEPAGE_ENV in os.environ:
        return
    os.environ[HUGEPAGE_ENV] = "0"
    if "numpy" in sys.modules:
        set_huge_pages(False)

def _proc_tree_rss() -> int | None:
    """:func:`process_tree_rss` from Linux's /proc (None elsewhere), as psutil reads it there (each process's
    parent from ``/proc/<pid>/stat``, its resident pages from ``/proc/<pid>/statm``). Read here because
    psutil's import alone is a twentieth of a 1,065-point run."""
    try:
        names = os.listdir("/proc")
        page = os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return None
    children: dict[int, list[int]] = {}
    for name in names:
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat", "rb") as f:
                    stat = f.read()
            except OSError:  # gone since the listing
                continue
            ppid = int(stat[stat.rindex(b")") + 2 :].split(maxsplit=2)[1])  # after "pid (name) state"
            children.setdefault(ppid, []).append(int(name))
    total, todo = 0, [os.getpid()]
    while todo:
        pid = todo.pop()
        todo += children.get(pid, [])
        try:
            with open(f"/proc/{pid}/statm", "rb") as f:
                total += int(f.read().split()[1]) * page
        except (OSError, IndexError, ValueError):
            continue
    return total


def process_tree_rss() -> int:
    """Resident memory of this process and its children now (bytes)."""
    rss = _proc_tree_rss()
    if rss is not None:
        return rss
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


def worker_rss() -> int:
    """Resident memory of the calling process (bytes): run on each worker by ``client.run``."""
    try:
        import psutil

        return int(psutil.Process().memory_info().rss)
    except ImportError:  # pragma: no cover
        import resource

        return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)


class PeakMemory:
    """Samples resident memory in a thread; a context manager.

    Attributes
    ----------
    peak : int
        The largest sample (bytes): of this process and its children, or,
        after :meth:`watch_workers`, of the sum over the cluster's workers.
    workers : int
        Workers in the largest sample (0: a local measure).
    scope : str
        What *peak* covers, for the summary: ``"this process and its
        children"`` or ``"2 dask workers (sum of their resident memory)"``.
    """

    def __init__(self, interval: float = 0.1, worker_interval: float = 1.0) -> None:
        self.interval = interval
        self.worker_interval = worker_interval
        self.peak = 0
        self.workers = 0
        self._client = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def scope(self) -> str:
        if self._client is None:
            return LOCAL_SCOPE
        return f"{self.workers} dask worker{'s' if self.workers != 1 else ''} (sum of their resident memory)"

    def watch_workers(self, client) -> None:
        """Measure the workers of *client* from now on, instead of this process."""
        self._client = client
        self.peak = 0
        self._sample()

    def sample(self) -> int:
        """Resident memory now (bytes): of this process and its children, or the workers' sum."""
        if self._client is None:
            return process_tree_rss()
        try:
            per_worker = self._client.run(worker_rss)
        except Exception as exc:  # a worker leaving mid-run must not fail the run
            logger.debug("worker memory not sampled: %s", exc)
            return 0
        if per_worker and sum(per_worker.values()) > self.peak:
            self.workers = len(per_worker)
        return int(sum(per_worker.values()))

    def _sample(self) -> None:
        self.peak = max(self.peak, self.sample())

    def _loop(self) -> None:
        while not self._stop.wait(self.interval if self._client is None else self.worker_interval):
            self._sample()

    def __enter__(self) -> PeakMemory:
        self._sample()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="cloudsieve-peak-memory")
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop sampling and take one last sample (again: nothing).

        Call it before the watched client closes: a ``client.run`` still in
        flight when its client closes never returns (dask.distributed
        2026.8), and the run would wait on it for ever.
        """
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=JOIN_SECONDS)
            if self._thread.is_alive():  # a worker that does not answer: the run goes on without its sample
                logger.warning("peak memory: the sampling thread did not stop within %d s", JOIN_SECONDS)
                return
        self._sample()

    def __exit__(self, *exc) -> None:
        self.stop()
