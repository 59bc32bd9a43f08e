"""Peak memory of a run: this process and its children, or the workers of a dask cluster.

:class:`PeakMemory` samples in a thread: locally the resident memory of this
process and its children (/proc on Linux); on a dask.distributed cluster
whose workers live elsewhere, the sum of the workers' own (psutil, through
``client.run``), the client excluded. :func:`small_pages` keeps numpy's
large arrays off transparent huge pages.
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
#: samples between two searches of /proc for this process's children (a search reads every process's
#: ``stat``; a sample reads the ``statm`` of the processes found)
TREE_EVERY = 10
#: how long stopping waits for a sample in flight
JOIN_SECONDS = 60
#: numpy's own switch of its huge-page advice, read when numpy is imported
HUGEPAGE_ENV = "NUMPY_MADVISE_HUGEPAGE"


def set_huge_pages(on: bool) -> bool:
    """Tell numpy whether to advise huge pages for large arrays; returns the previous setting (False,
    unchanged, for a numpy without this private switch)."""
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):  # numpy 2, numpy 1
        try:
            switch = importlib.import_module(module)._set_madvise_hugepage
        except (ImportError, AttributeError):
            continue
        return bool(switch(bool(on)))
    return False


@contextlib.contextmanager
def small_pages():
    """Inside, numpy's arrays of 4 MiB and more go on 4 KiB pages, unless ``NUMPY_MADVISE_HUGEPAGE`` is set.

    The kernel zeroes a whole 2 MiB huge page at first touch, slow on a
    virtual machine (docs/architecture.md, "Design reasons"). The switch is
    process-wide; it is restored on leaving.
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
    """:func:`small_pages` for the rest of this process and its children (through the environment
    variable numpy reads at import), unless ``NUMPY_MADVISE_HUGEPAGE`` is set."""
    if HUGEPAGE_ENV in os.environ:
        return
    os.environ[HUGEPAGE_ENV] = "0"
    if "numpy" in sys.modules:
        set_huge_pages(False)


def _proc_tree() -> list[int] | None:
    """This process and its descendants from Linux's /proc (None elsewhere), found as psutil does, without its
    import: every process's parent read from its ``stat``."""
    try:
        names = os.listdir("/proc")
    except OSError:
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
    tree, todo = [], [os.getpid()]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo += children.get(pid, [])
    return tree


def _proc_rss(pids: list[int]) -> int:
    """Resident memory of the processes *pids* (bytes) from their ``statm``; a process gone counts 0."""
    page, total = os.sysconf("SC_PAGE_SIZE"), 0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/statm", "rb") as f:
                total += int(f.read().split()[1]) * page
        except (OSError, IndexError, ValueError):
            continue
    return total


def _proc_tree_rss() -> int | None:
    """:func:`process_tree_rss` from Linux's /proc (None elsewhere)."""
    tree = _proc_tree()
    return None if tree is None else _proc_rss(tree)


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

    *peak*: the largest sample (bytes), of this process and its children, or
    after :meth:`watch_workers` summed over the cluster's workers; *workers*:
    workers in that sample (0: local); *scope*: what *peak* covers.
    """

    def __init__(self, interval: float = 0.1, worker_interval: float = 1.0) -> None:
        self.interval = interval
        self._tree: list[int] | None = None  # the processes sampled (/proc), found again every TREE_EVERY samples
        self._samples = 0
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
            if self._tree is None or self._samples % TREE_EVERY == 0:
                self._tree = _proc_tree()
            self._samples += 1
            return process_tree_rss() if self._tree is None else _proc_rss(self._tree)
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

        Call it before the watched client closes: a ``client.run`` in flight
        then never returns.
        """
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=JOIN_SECONDS)
            if self._thread.is_alive():  # a worker that does not answer
                logger.warning("peak memory: the sampling thread did not stop within %d s", JOIN_SECONDS)
                return
        self._sample()

    def __exit__(self, *exc) -> None:
        self.stop()
