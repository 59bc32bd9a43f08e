"""Imported by the local fork server at start-up (see :mod:`cloudsieve.lifeline`).

It is the last module of the fork server's preload list: imported there, it
asks the kernel to kill the fork server when its parent, the driver, dies,
skips the imports of :mod:`cloudsieve.lean_start` (so do the workers forked
from it), then compiles the numba kernels of the run's warm-up targets (named
by the driver in ``CLOUDSIEVE_WARM_UP``, :func:`.pool.start_forkserver`; the
scoring path without it), or loads them from numba's cache, once, so every worker
forked from the server inherits them
(:func:`cloudsieve.core.warmup.warm_up`), and freezes the objects it
holds (``gc.freeze``) before the first fork.
Imported anywhere else (a test that imports every preload module) it does
nothing: the caller is recognised by ``multiprocessing.forkserver.main`` on
the import's call stack.
"""

import gc
import logging
import os
import sys

from ..core.warmup import warm_up
from ..rule_table import TARGETS
from ..lifeline import die_with_parent
from ..lean_start import skip_unused_imports
from .pool import WARM_UP_ENV


def _in_forkserver_main() -> bool:
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "main" and frame.f_globals.get("__name__") == "multiprocessing.forkserver":
            return True
        frame = frame.f_back
    return False


if _in_forkserver_main():
    die_with_parent()
    skip_unused_imports()  # before the warm-up loads numba's array module; the workers inherit the hook
    try:
        _targets = [t for t in os.environ.get(WARM_UP_ENV, "common,partition,scores").split(",") if t in TARGETS]
        logging.getLogger(__name__).debug("kernels of %s warmed up in %.2f s", _targets, warm_up(_targets))
    except Exception as exc:  # noqa: BLE001 - the workers then compile at their first call, and raise there
        logging.getLogger(__name__).warning("kernel warm-up failed in the fork server: %r", exc)
    # the objects of the imports and the kernels, frozen before any fork: the workers' collections do not
    # walk them (the collections of a worker's tasks take about half the time), and do not write to their
    # pages (Python's advice for a parent that forks)
    gc.freeze()
