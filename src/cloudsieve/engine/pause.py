"""A test hook: stop a run at a named point, so a test interrupts it there and not by racing it.

``CLOUDSIEVE_TEST_PAUSE_AT=<point>=<marker file>``: at *point* the run appends
its pid to the marker file and blocks until a signal or the file's removal.
Points: ``driver:<stage>`` (before the stage's tasks start), ``task:<stage>``
(each task, in its worker), ``task:<stage>#<n>`` (the n-th task to start in a
process), ``task:<stage>#once`` (the first task in any process).
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable

__all__ = ["PAUSE_ENV", "paused", "pause_at", "pausing_task"]

PAUSE_ENV = "CLOUDSIEVE_TEST_PAUSE_AT"


_arrivals: dict[str, itertools.count] = {}  # point -> calls of pause_at there in this process


def paused(point: str) -> str | None:
    """The marker file when the environment asks to pause at *point*, else None."""
    value = os.environ.get(PAUSE_ENV)
    if not value:
        return None
    want, _, marker = value.partition("=")
    return marker if want.partition("#")[0] == point and marker else None


def pause_at(point: str) -> None:
    """Block at *point* when the environment asks to (module docstring); return at once otherwise."""
    marker = paused(point)
    if marker is None:
        return
    nth = os.environ[PAUSE_ENV].partition("=")[0].partition("#")[2]
    if nth == "once":
        try:
            fd = os.open(marker, os.O_WRONLY | os.O_CREAT | os.O_EXCL)
        except FileExistsError:  # another task stopped first
            return
        os.write(fd, f"{os.getpid()}\n".encode())
        os.close(fd)
    else:
        if nth and next(_arrivals.setdefault(point, itertools.count(1))) != int(nth):
            return
        with open(marker, "a") as fh:  # O_APPEND: lines never interleave
            fh.write(f"{os.getpid()}\n")
    while os.path.exists(marker):  # a signal ends it
        time.sleep(0.1)  # removed marker: the run goes on


def pausing_task(func: Callable, stage: str) -> Callable:
    """*func*, or when the environment asks to pause at ``task:<stage>``, *func* after that pause."""
    if paused(f"task:{stage}") is None:
        return func
    import functools

    wrapped = functools.partial(_paused_call, f"task:{stage}", func)
    wrapped.__name__ = getattr(func, "__name__", "task")  # the runner names task keys after it
    return wrapped


def _paused_call(point: str, func: Callable, *args):
    pause_at(point)
    return func(*args)  # pragma: no cover - pause_at never returns here
