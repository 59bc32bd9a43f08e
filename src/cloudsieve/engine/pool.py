"""The local worker processes of the default scheduler: how they start, what they load, how long they live.

:func:`local_pool` is a run's one process pool; its workers are forked by a
fork server that imported the engine once (``_PRELOAD``), die with it
(:mod:`cloudsieve.lifeline`) and are replaced after ``_TASKS_PER_CHILD`` tasks.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor

from ..lifeline import die_with_parent

__all__ = ["local_pool", "worker_context", "preload", "start_forkserver", "WARM_UP_ENV"]

#: environment variable naming the warm-up targets the fork server compiles, comma-separated
WARM_UP_ENV = "CLOUDSIEVE_WARM_UP"

#: tasks a worker runs before it is replaced (bounds slow growth; a fresh worker's first task costs more)
_TASKS_PER_CHILD = 64
#: modules imported once by the fork server, so a replaced worker starts in milliseconds
_PRELOAD = ["numpy", "zarr", "cloudsieve.store", "cloudsieve.core", "cloudsieve.engine",
            "cloudsieve.engine.partition", "cloudsieve.engine.label", "cloudsieve.engine.runs", "cloudsieve.engine.halo",
            "cloudsieve.engine.cells", "cloudsieve.engine.threshold", "cloudsieve.engine.merge",
            # numba and the compiled kernels (the workers inherit the code)
            "cloudsieve.core.warmup",
            # last: dies with the driver and warms up the kernels
            "cloudsieve.engine.forkserver_init"]
#: imported by the scoring path's tasks only (a third of the fork server's imports, which the first tasks wait for)
_SCORING = ["scipy.spatial", "cloudsieve.core.kernels.knn", "cloudsieve.core.kernels.entropy"]


def worker_context():
    """The multiprocessing context of the local workers: a "forkserver" that imported everything once
    (clean like dask's default "spawn", without its seconds of start-up), unless dask configures one."""
    import multiprocessing as mp

    import dask
    from dask.multiprocessing import get_context

    if dask.config.get("multiprocessing.context", None) is None and "forkserver" in mp.get_all_start_methods():
        return mp.get_context("forkserver")  # preload: start_forkserver's
    return get_context()


def preload(targets: Iterable[str]) -> list[str]:
    """The fork server's preload list for *targets*: the scoring modules only when a target scores.

    >>> "scipy.spatial" in preload(("common", "partition", "eliminate"))
    False
    >>> "scipy.spatial" in preload(("common", "partition", "scores"))
    True
    """
    scoring = not set(targets) <= {"common", "partition", "eliminate"}
    return _PRELOAD[:-2] + (_SCORING if scoring else []) + _PRELOAD[-2:]


def start_forkserver(context, targets: Iterable[str]) -> None:
    """Start the fork server of a "forkserver" *context* now, warming up *targets* (:mod:`.forkserver_init`).

    Workers inherit the compiled kernels, so no two compile the same one. A
    fork server already running in this process is kept.
    """
    if context.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver

    targets = tuple(targets)
    context.set_forkserver_preload(preload(targets))
    before = os.environ.get(WARM_UP_ENV)
    os.environ[WARM_UP_ENV] = ",".join(targets)  # the fork server inherits this environment
    try:
        forkserver.ensure_running()
    finally:
        if before is None:
            os.environ.pop(WARM_UP_ENV, None)
        else:
            os.environ[WARM_UP_ENV] = before


def local_pool(workers: int, context) -> ProcessPoolExecutor:
    """A pool of *workers* local worker processes started with *context* (:func:`worker_context`)."""
    return ProcessPoolExecutor(workers, mp_context=context, max_tasks_per_child=_TASKS_PER_CHILD,
                               initializer=_worker_init)


def _worker_init() -> None:
    """A local worker process: dies with the fork server; glibc's heap thresholds fixed (:func:`bound_malloc`)."""
    from ..store.streaming import bound_malloc

    die_with_parent()
    bound_malloc()
