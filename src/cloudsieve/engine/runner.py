"""The one task runner: :class:`Runner` runs batches of independent calls on dask.

Used by the engine's stages and the evaluation's; its local process pool is
:mod:`.pool`'s, streamed and forked calls are :mod:`.calls`'.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from .. import storage, storage_retries
from ..errors import InvalidParameterError
from ..progress import stage_bar
from .. import handles
from . import ahead
from .memory import PeakMemory  # noqa: F401  (re-exported)
from .pause import pause_at, pausing_task
from .pool import local_pool, start_forkserver, worker_context

__all__ = ["Runner", "PeakMemory", "DEFAULT_SCHEDULER"]

logger = logging.getLogger(__name__)

#: the embedded default local scheduler (faster than threads: see :class:`Runner`)
DEFAULT_SCHEDULER = "processes"

#: a LocalCluster's scheduler serves HTTP even without a dashboard: any free port, not a clash on 8787
NO_HTTP_PORT = {"dashboard_address": ":0"}


def boot(scheduler, memory_limit, warm: tuple[str, ...]) -> None:
    """Start the fork server a :class:`Runner` of these options will use, now; nothing for other schedulers.

    For a caller that knows a run needs the local pool before it imports the
    stages: the fork server's imports and warm-up then overlap the caller's.
    The Runner keeps the running fork server (:func:`.pool.start_forkserver`).
    """
    if memory_limit is not None or (scheduler or DEFAULT_SCHEDULER) != "processes":
        return
    start_forkserver(worker_context(), warm)


class Runner:
    """Runs batches of independent tasks on the chosen dask scheduler.

    ``runner(func, argument_tuples, stage)`` returns the results in argument
    order, whatever the completion order.

    Parameters
    ----------
    scheduler : str, optional
        None (:data:`DEFAULT_SCHEDULER`): dask's "processes" scheduler with one
        process pool for the whole run (the in-memory method holds the GIL in
        its Python parts), or with *memory_limit* a
        :class:`distributed.LocalCluster` of capped workers. "sync",
        "threads", "processes": dask's local schedulers. "tcp://host:port": an
        existing dask.distributed cluster whose workers reach the store.
    workers, memory_limit, client, bars
        As :func:`cloudsieve.engine.simplify` takes them.
    warm : tuple of str
        Warm-up targets (:func:`cloudsieve.rule_table.targets_of`) the pool's
        fork server compiles before it forks a worker.
    """

    def __init__(self, scheduler=None, workers=None, memory_limit=None, client=None, bars=None,
                 warm: tuple[str, ...] = ("common", "partition", "scores")) -> None:
        self.client = client
        self._own_client = False
        self._cluster = None
        self.workers = workers
        self.bars = bars
        self._stages: dict[str, Callable[[int], None]] = {}  # open :meth:`stage` blocks
        self._pool = None  # the local process pool ("processes")
        self._prestart: threading.Thread | None = None
        self.task_cpu = 0.0  # CPU seconds of the local pool's tasks
        self.task_retries = 0  # object-store retries in those tasks
        self._cpu_start: dict | None = None  # each distributed worker's (CPU, retries) at the start
        self._cpu_closed: tuple[float, int] | None = None  # :meth:`worker_counts` at close
        self._ahead = None  # a process compiling kernels ahead (:mod:`.ahead`)
        if client is not None:
            self.name = f"distributed ({getattr(client, 'scheduler', None) and client.scheduler.address})"
            self._cpu_start = _workers_cpu(client)
            return
        if isinstance(scheduler, str) and "://" in scheduler:
            from ..scheduler import connect

            self.client = connect(scheduler)
            self._own_client = True
            self.name = f"distributed ({scheduler})"
            self._cpu_start = _workers_cpu(self.client)
            return
        if memory_limit is not None:
            if scheduler not in (None, "processes"):
                raise InvalidParameterError(
                    f"memory_limit ({memory_limit}) needs worker processes: use the default scheduler or 'processes', not {scheduler!r}"
                )
            from distributed import Client, LocalCluster

            n = int(workers or os.cpu_count() or 1)
            self._cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                memory_limit=memory_limit,
                host="127.0.0.1",
                dashboard_address=None,
                scheduler_kwargs=NO_HTTP_PORT,
            )
            self.client = Client(self._cluster)
            self._own_client = True
            self.name = f"local cluster ({n} workers, memory limit {memory_limit})"
            self._cpu_start = _workers_cpu(self.client)
            return
        if scheduler is None:
            scheduler = DEFAULT_SCHEDULER
        if scheduler not in ("sync", "synchronous", "threads", "processes"):
            raise InvalidParameterError(
                f"unknown scheduler {scheduler!r}: use sync, threads, processes or a tcp://host:port address"
            )
        self.local = "sync" if scheduler == "synchronous" else scheduler
        self.name = self.local + (f" ({workers} workers)" if workers and self.local != "sync" else "")
        self._ahead = ahead.start(warm)
        if self.local == "processes":
            # one pool for the whole run: dask would start a new pool at every compute()
            self._context = worker_context()
            start_forkserver(self._context, warm)  # warms up while the driver ingests
            self._pool = local_pool(int(workers or os.cpu_count() or 1), self._context)

    @property
    def task_threads(self) -> int:
        """k-d tree threads per cell task: the cores shared by the tasks running at once.

        One local worker gets every core; a dask.distributed cluster's workers
        are assumed to fill their machines (1). Results do not depend on it.
        """
        cores = os.cpu_count() or 1
        if self.client is not None and self._cluster is None:
            return 1
        if getattr(self, "local", None) == "sync":
            return cores
        return max(1, cores // int(self.workers or cores))

    @property
    def remote_client(self):
        """The client of a dask.distributed cluster this runner did not start, or None."""
        return self.client if self.client is not None and self._cluster is None else None

    @property
    def dashboard_link(self) -> str | None:
        """The dask dashboard of a distributed run, or None."""
        if self.client is None:
            return None
        with contextlib.suppress(Exception):
            return self.client.dashboard_link
        return None

    def prestart(self) -> None:
        """Start the local pool's worker processes now, in a background thread, and return.

        Overlaps the workers' start-up (fork server, preload imports, kernels)
        with the ingest; tasks and results are the same.
        """
        pool = self._pool
        # a thread's spawned children die with it (PR_SET_PDEATHSIG)
        if pool is None or self._prestart is not None or self._context.get_start_method() != "forkserver":
            return
        from multiprocessing import forkserver

        # the fork server from this long-lived thread: it dies with the thread that starts it
        forkserver.ensure_running()
        n = int(self.workers or os.cpu_count() or 1)

        def start() -> None:
            with contextlib.suppress(RuntimeError):  # the pool was shut down first
                for _ in range(n):
                    pool.submit(os.getpid)
                # CPython's executor starts a worker only when none is idle: start the rest here
                with pool._shutdown_lock:
                    while not pool._shutdown_thread and len(pool._processes) < n:
                        pool._spawn_process()

        self._prestart = threading.Thread(target=start, name="cloudsieve-prestart", daemon=True)
        self._prestart.start()

    def worker_cpu(self) -> float:
        """CPU seconds the worker processes spent on this run so far (0 when tasks run in this process).

        The local pool sums its tasks' CPU times; a dask.distributed cluster
        sums each worker's CPU since the start (a worker that left is missed).
        """
        return self.worker_counts()[0]

    def worker_counts(self) -> tuple[float, int]:
        """``(worker_cpu(), object-store retries in the workers so far)``, counted as the CPU is."""
        if self._cpu_closed is not None:
            return self._cpu_closed
        if self.client is not None and self._cpu_start is not None:
            now = _workers_cpu(self.client)
            start = self._cpu_start
            return (float(sum(max(0.0, v[0] - start.get(w, (0.0, 0))[0]) for w, v in now.items())),
                    int(sum(max(0, v[1] - start.get(w, (0.0, 0))[1]) for w, v in now.items())))
        return float(self.task_cpu), int(self.task_retries)

    def close(self) -> None:
        """Shut down the process pool and the client/cluster this runner started (again: nothing)."""
        if self._ahead is not None:
            ahead.finish(self._ahead)
            self._ahead = None
        if self._pool is not None:
            if self._prestart is not None:
                self._prestart.join()
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._own_client and self.client is not None:
            self._cpu_closed = self.worker_counts()  # a closed client cannot ask its workers
            self.client.close()
            self._own_client = False
        if self._cluster is not None:
            self._cluster.close()

    @contextlib.contextmanager
    def stage(self, stage: str, unit: str = "task") -> Iterator[None]:
        """One bar (or log line) for every batch of stage *stage* run inside the block (e.g. threshold rounds)."""
        with stage_bar(self.bars, stage, None, unit) as update:
            self._stages[stage] = update
            try:
                yield
            finally:
                del self._stages[stage]

    def __call__(self, func: Callable, args: Sequence[tuple], stage: str, unit: str = "task",
                 after: Sequence[Sequence[int]] | None = None) -> list:
        """``[func(*a) for a in args]`` as tasks of stage *stage*, results in argument order.

        *after*, one sequence per task: indices of earlier tasks that must
        finish before it starts. None: all in parallel.
        """
        args = list(args)
        if not args:
            return []
        deps = [()] * len(args) if after is None else [tuple(int(j) for j in a) for a in after]
        if len(deps) != len(args) or any(not 0 <= j < i for i, d in enumerate(deps) for j in d):
            raise InvalidParameterError("after must list, for each task, indices of earlier tasks only")
        if stage in self._stages:  # inside :meth:`stage`: its bar counts these tasks too
            return self._run(func, args, deps, stage, self._stages[stage])
        with stage_bar(self.bars, stage, len(args), unit) as update:
            return self._run(func, args, deps, stage, update)

    def _run(self, func, args, deps, stage, update) -> list:
        pause_at(f"driver:{stage}")  # a test's stop (engine/pause.py)
        func = storage.bound(pausing_task(func, stage))  # the run's storage options, in any process
        func = handles.per_stage(func)  # store handles opened once per stage in a worker
        if self.client is not None:
            return self._distributed(func, args, deps, stage, update)
        return self._local(func, args, deps, update)

    def _distributed(self, func, args, deps, stage, update) -> list:
        from distributed import as_completed

        token = uuid.uuid4().hex[:8]
        tag = stage.replace(" ", "").replace(":", "-")
        futures: list = []
        args = [tuple(_scattered(self.client, x) for x in a) for a in args]
        for i, a in enumerate(args):
            key = f"cloudsieve-{tag}-{i}-{token}"
            if deps[i]:  # futures as arguments: started once they are done
                f = self.client.submit(_after, func, len(a), *a, *[futures[j] for j in deps[i]], key=key, pure=False)
            else:
                f = self.client.submit(func, *a, key=key, pure=False)
            futures.append(f)
        try:
            for _ in as_completed(futures):
                update(1)
            return self.client.gather(futures)
        finally:
            for f in futures:
                f.release()

    def _local(self, func, args, deps, update) -> list:
        import dask
        from dask.callbacks import Callback

        # keys sorting in reverse argument order make dask's local scheduler start
        # tasks in argument order (the cells stage starts the largest first)
        token = uuid.uuid4().hex[:8]
        last = len(args) - 1
        tasks: list = []
        name = func.__name__
        timed = self._pool is not None
        if timed:  # each task's CPU and retries, measured in its worker
            func = functools.partial(_timed, func)
        for i, a in enumerate(args):
            key = f"cloudsieve-{name}-{token}-{last - i:09d}"
            if deps[i]:  # delayed arguments: graph dependencies
                t = dask.delayed(_after, pure=False)(func, len(a), *a, *[tasks[j] for j in deps[i]], dask_key_name=key)
            else:
                t = dask.delayed(func, pure=False)(*a, dask_key_name=key)
            tasks.append(t)
        keys = {t.key for t in tasks}

        class _Count(Callback):
            def _posttask(self, key, result, dsk, state, worker_id):
                if key in keys:
                    update(1)

        # the scheduler as a function: a name makes dask import distributed
        from dask import local, multiprocessing, threaded

        get = {"sync": local.get_sync, "threads": threaded.get, "processes": multiprocessing.get}[self.local]
        kwargs: dict[str, Any] = {"scheduler": get}
        if self.workers and self.local != "sync":
            kwargs["num_workers"] = int(self.workers)
        if self._pool is not None:
            kwargs["pool"] = self._pool
            kwargs["chunksize"] = 1  # dask's default batches 6 tasks per worker
        with _Count():
            results = list(dask.compute(*tasks, **kwargs))
        if timed:
            self.task_cpu += sum(cpu for _, cpu, _ in results)
            self.task_retries += sum(retries for _, _, retries in results)
            results = [r for r, _, _ in results]
        return results


#: an array argument larger than this goes to the workers ahead of its task (below dask's 10 MiB graph warning)
SCATTER_BYTES = 1 << 20


def _scattered(client, value):
    """*value*, or a future of it on the workers when it is an array above ``SCATTER_BYTES`` (the partition's
    sample: up to 24 MB): dask.distributed sends a task's arguments with the graph and warns above 10 MiB."""
    import numpy as np

    if isinstance(value, np.ndarray) and value.nbytes > SCATTER_BYTES:
        return client.scatter(value, hash=False)
    return value


def _timed(func: Callable, *args):
    """``(func(*args), CPU seconds, object-store retries)`` of a task in a worker process."""
    t0, r0 = time.process_time(), storage_retries.counts()[1]
    result = func(*args)
    return result, time.process_time() - t0, storage_retries.counts()[1] - r0


def _process_counts() -> tuple[float, int]:
    return time.process_time(), storage_retries.counts()[1]


def _workers_cpu(client) -> dict:
    """Each dask.distributed worker's (CPU seconds, object-store retries), by address."""
    try:
        return {w: (float(v[0]), int(v[1])) for w, v in client.run(_process_counts).items()}
    except Exception:  # pragma: no cover - a cluster that refuses client.run
        return {}


def _after(func: Callable, n: int, *args):
    """``func(*args[:n])``: the other arguments are the results of the tasks it waited for."""
    return func(*args[:n])
