"""Helper processes die with the process that started them.

A ``kill -9`` of a running ``cloudsieve simplify`` gives its children no chance
to clean up: without this, the fork server and the worker processes it
forked stay alive (a few hundred MB each), and the multiprocessing resource
tracker with them (it exits when the last holder of its pipe does).

On Linux a process can ask the kernel to send it a signal when its parent
dies (``prctl(PR_SET_PDEATHSIG)``): the fork server asks for SIGKILL when the
driver dies (it imports :mod:`cloudsieve.engine.forkserver_init` at start-up),
and every worker asks for SIGKILL when the fork server dies (the pool's
initializer). So the whole tree goes with the driver, whatever killed it.
Elsewhere :func:`die_with_parent` starts a watchdog thread that polls the
parent's pid instead.
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
    """End this process (SIGKILL) as soon as its parent process ends.

    Parameters
    ----------
    expected_parent : int, optional
        The parent's pid as the parent saw it. If the parent is already gone
        when this runs (a death between fork and this call), exit at once.
    """
    parent = os.getppid() if expected_parent is None else int(expected_parent)
    if not _prctl_deathsig(signal.SIGKILL):
        threading.Thread(target=_watchdog, args=(parent,), daemon=True, name="cloudsieve-lifeline").start()
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)
