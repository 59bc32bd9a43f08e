"""Imported by the local fork server at start-up, the last of its preload list (:func:`.pool.preload`).

There it makes the fork server die with the driver (:mod:`cloudsieve.lifeline`),
skips :mod:`cloudsieve.lean_start`'s imports, warms up the kernels of the
targets in ``CLOUDSIEVE_WARM_UP`` (:func:`cloudsieve.core.warmup.warm_up`)
so every worker inherits them, and freezes its objects before the first
fork. Imported anywhere else (no ``multiprocessing.forkserver.main`` on the
call stack) it does nothing.
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
    skip_unused_imports()  # before numba's array module loads; workers inherit the hook
    try:
        _targets = [t for t in os.environ.get(WARM_UP_ENV, "common,partition,scores").split(",") if t in TARGETS]
        logging.getLogger(__name__).debug("kernels of %s warmed up in %.2f s", _targets, warm_up(_targets))
    except Exception as exc:  # noqa: BLE001 - workers then compile at first call
        logging.getLogger(__name__).warning("kernel warm-up failed in the fork server: %r", exc)
    # frozen before any fork: the workers' garbage collections neither walk nor write these pages
    gc.freeze()
