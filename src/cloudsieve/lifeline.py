"""Helper processes die with the process that started them.

A ``kill -9`` of the driver would leave the fork server, its workers and the
resource tracker alive. On Linux each asks the kernel for SIGKILL when its
parent dies (``prctl(PR_SET_PDEATHSIG)``): the fork server at start-up
(:mod:`cloudsieve.engine.forkserver_init`), the workers in the pool's
initializer. Elsewhere :func:`die_with_parent` polls the parent's pid.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import sys
import threading

__all__ = ["die_with_parent"]

_PR_SET_PDEATHSIG = 1
_POLL_SECONDS = 1.0


def _prctl_deathsig(sig: int) -> bool:
    if not sys.platform.startswith("linux"):
        return False
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    return False


def _watchdog(parent: int) -> None:
    # the parent died when we were re-parented (to init or a subreaper)
    while True:
        threading.Event().wait(_POLL_SECONDS)
        if os.getppid() != parent:
            os._exit(1)


def die_with_parent(expected_parent: int | None = None) -> None:
    """End this process (SIGKILL) as soon as its parent ends; at once if *expected_parent* (its pid) is already gone."""
    parent = os.getppid() if expected_parent is None else int(expected_parent)
    if not _prctl_deathsig(signal.SIGKILL):
        threading.Thread(target=_watchdog, args=(parent,), daemon=True, name="cloudsieve-lifeline").start()
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)
