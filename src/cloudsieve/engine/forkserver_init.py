"""Imported by the local fork server at start-up (see :mod:`cloudsieve.engine.lifeline`).

It is the last module of the fork server's preload list: imported there, it
asks the kernel to kill the fork server when its parent, the driver, dies.
Imported anywhere else (a test that imports every preload module) it does
nothing: the caller is recognised by ``multiprocessing.forkserver.main`` on
the import's call stack.
"""

import sys

from .lifeline import die_with_parent


def _in_forkserver_main() -> bool:
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "main" and frame.f_globals.get("__name__") == "multiprocessing.forkserver":
            return True
        frame = frame.f_back
    return False


if _in_forkserver_main():
    die_with_parent()
