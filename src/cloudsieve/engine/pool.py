"""The local worker processes of the default scheduler: how they start, what they load, how long they live.

:func:`local_pool` is the one process pool of a run (:class:`.runner.Runner`
with dask's "processes" scheduler). Its workers are forked by a fork server
that has imported the engine once (:func:`worker_context`, ``_PRELOAD``),
die with it (:mod:`cloudsieve.lifeline`), keep glibc's heap thresholds fixed
(:func:`~cloudsieve.store.streaming.bound_malloc`) and are replaced after
``_TASKS_PER_CHILD`` tasks.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor

from ..lifeline import die_with_parent

__all__ = ["local_pool", "worker_context", "preload", "start_forkserver", "WARM_UP_ENV"]

#: the environment variable naming the warm-up targets the fork server compiles, comma-separated
#: (:data:`cloudsieve.rule_table.TARGETS`; set only while :func:`start_forkserver` starts it)
WARM_UP_ENV = "CLOUDSIEVE_WARM_UP"

#: tasks a local worker process runs before it is replaced (a bound on any slow growth of a long-lived
#: process; the heap's thresholds are fixed by bound_malloc). A replaced worker's first task costs more
#: (numba's cache, fresh pages): replaced every 8 tasks, the workers' cells stage takes a tenth longer
_TASKS_PER_CHILD = 64
#: modules imported once by the fork server, so a replaced worker starts in milliseconds
_PRELOAD = ["numpy", "zarr", "cloudsieve.store", "cloudsieve.core", "cloudsieve.engine",
            "cloudsieve.engine.partition", "cloudsieve.engine.label", "cloudsieve.engine.runs", "cloudsieve.engine.halo",
            "cloudsieve.engine.cells", "cloudsieve.engine.threshold", "cloudsieve.engine.merge",
            # numba and the compiled kernels (forkserver_init warms them up: workers inherit the code)
            "cloudsieve.core.warmup",
            # last: the fork server asks to die with the driver (see cloudsieve/lifeline.py) and warms up the kernels
            "cloudsieve.engine.forkserver_init"]
#: what only the scoring path's tasks (the entropy rules, evaluate) import: scipy's k-d tree and the scoring
#: kernels. A run of the default rule leaves them out: they are about a third of the fork server's imports,
#: and the first tasks of a run wait for it
_SCORING = ["scipy.spatial", "cloudsieve.core.kernels.knn", "cloudsieve.core.kernels.entropy"]


def worker_context():
    """The multiprocessing context of the local worker processes.

    dask's default is "spawn": every new process starts Python and imports
    numpy, scipy, zarr and cloudsieve again (seconds, not milliseconds), and workers are
    replaced every ``_TASKS_PER_CHILD`` tasks. Where available (and unless
    dask's ``multiprocessing.context`` is configured) a "forkserver" that has
    imported them once forks the workers instead: a clean single-threaded
    parent, like spawn, without the start-up cost.
    """
    import multiprocessing as mp

    import dask
    from dask.multiprocessing import get_context

    if dask.config.get("multiprocessing.context", None) is None and "forkserver" in mp.get_all_start_methods():
        return mp.get_context("forkserver")  # its preload list: start_forkserver's, for the run's targets
    return get_context()


def preload(targets: Iterable[str]) -> list[str]:
    """The fork server's preload list for worker tasks whose kernels are warm-up *targets*: the scoring
    path's modules only when a target scores (every target but the default rule's).

    >>> "scipy.spatial" in preload(("common", "partition", "eliminate"))
    False
    >>> "scipy.spatial" in preload(("common", "partition", "scores"))
    True
    """
    scoring = not set(targets) <= {"common", "partition", "eliminate"}
    return _PRELOAD[:-2] + (_SCORING if scoring else []) + _PRELOAD[-2:]


def start_forkserver(context, targets: Iterable[str]) -> None:
    """Start the fork server of *context* now (a "forkserver" context only), warming up *targets*.

    The fork server compiles (or loads from numba's cache) the kernels of
    *targets* once, before it forks a worker
    (:mod:`.forkserver_init`): the workers inherit them, and two workers
    never compile the same kernel side by side. It is one per process: a
    fork server already running (started by a run before, in this process) is kept,
    and its workers load what else they need from the cache.
    """
    if context.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver

    targets = tuple(targets)
    context.set_forkserver_preload(preload(targets))
    before = os.environ.get(WARM_UP_ENV)
    os.environ[WARM_UP_ENV] = ",".join(targets)  # the fork server's environment is this process's
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
    bound_malloc()  # as the driver: see its docstring
