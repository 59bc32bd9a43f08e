"""Calls outside the runner's batches, for the evaluation: :func:`imap` streams calls (here or on a dask
client, a bounded number in flight); :func:`forked` runs each call in a forked child."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from ..errors import CloudsieveError

__all__ = ["imap", "forked"]

logger = logging.getLogger(__name__)


def imap(func: Callable, items: Iterable[tuple[tuple, dict]], client: Any = None, shared: Sequence[Any] = (),
         kwargs: dict | None = None, max_inflight: int | None = None) -> Iterator[Any]:
    """Yield ``func(*args, *shared, **kw, **kwargs)`` for each ``(args, kw)`` of *items*, in item order.

    Without a *client* the calls run here in turn. With a dask.distributed
    *client* they are tasks, at most *max_inflight* (default: twice the
    workers) pending, so *items* may be a generator over data larger than
    memory; each of *shared* is scattered once to every worker.
    """
    kwargs = kwargs or {}
    if client is None:
        for args, kw in items:
            yield func(*args, *shared, **kw, **kwargs)
        return
    nworkers = max(len(client.scheduler_info().get("workers", {})), 1)
    max_inflight = max_inflight or 2 * nworkers
    extra = [client.scatter(a, broadcast=True) for a in shared]
    pending = []
    for args, kw in items:
        pending.append(client.submit(func, *args, *extra, **kw, **kwargs, pure=False))
        while len(pending) >= max_inflight:
            yield pending.pop(0).result()
    while pending:
        yield pending.pop(0).result()


def _child(conn, fn, args):  # pragma: no cover - runs in the forked child
    try:
        conn.send(("ok", fn(*args)))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


def forked(calls: Sequence[tuple], max_parallel: int | None = None, name: str = "pymeshlab") -> list:
    """Run each ``(fn, *args)`` of *calls* in its own forked child, up to *max_parallel* at once; results in order.

    A child starts from the parent's state and ends with its call, so a
    library with hidden process-wide state (pymeshlab's Metro sampling, whose
    random generator is never reseeded: :mod:`cloudsieve.evaluate.mesh`) gives
    the same result for the same call. *fn* and its arguments need not
    pickle, the result must. Without ``fork`` the calls run here in turn.
    *name* names the calls in messages.

    Raises
    ------
    CloudsieveError
        A call raised (its type and message are given) or its child died.
    """
    import multiprocessing as mp

    try:
        ctx = mp.get_context("fork")
    except ValueError:  # pragma: no cover
        logger.info("no fork: %s calls run in process; results that depend on process state vary between calls", name)
        return [c[0](*c[1:]) for c in calls]
    max_parallel = max_parallel or os.cpu_count() or 1
    results: list = [None] * len(calls)
    running: list = []

    def finish(item):
        i, proc, conn = item
        try:
            status, value = conn.recv()
        except EOFError:
            proc.join()
            raise CloudsieveError(f"{name} crashed in its worker process (exit code {proc.exitcode})") from None
        proc.join()
        conn.close()
        if status != "ok":
            raise CloudsieveError(f"{name} failed: {value}")
        results[i] = value

    for i, call in enumerate(calls):
        if len(running) >= max_parallel:
            finish(running.pop(0))
        parent, child = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_child, args=(child, call[0], call[1:]), daemon=True)
        proc.start()
        child.close()
        running.append((i, proc, parent))
    while running:
        finish(running.pop(0))
    return results
