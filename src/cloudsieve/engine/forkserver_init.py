"""Imported by the local fork server at start-up (see :mod:`cloudsieve.engine.lifeline`).

It is the last module of the fork server's preload list: imported there, it
asks the kernel to kill the fork server when its parent, the driver, dies,
then compiles the numba kernels (or loads them from numba's cache) once, so
every worker forked from the server inherits them
(:func:`cloudsieve.core.kernels.warmup.warm_up` and, for the ``eliminate``
rule, :func:`warm_up_eliminate`).
Imported anywhere else (a test that imports every preload module) it does
nothing: the caller is recognised by ``multiprocessing.forkserver.main`` on
the import's call stack.
"""

import logging
import sys
import time

import numpy as np

from ..core.kernels.warmup import warm_up
from .lifeline import die_with_parent


def warm_up_eliminate() -> float:
    """Run the ``eliminate`` rule's cell path once on a tiny cell (its kernels: the grid, neighbour lists,
    elimination, relocation; the count pass's copies and areas), so the workers inherit them too: a worker
    is replaced every few tasks, and loading them from numba's cache costs each new one ~0.06 s."""
    from ..core.duplicates import exact_copies
    from ..core.eliminate import eliminate_cell
    from ..core.radius import point_areas

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    pts = rng.random((64, 3)) * [1.0, 1.0, 0.01]
    halo = rng.random((16, 3)) * [1.0, 1.0, 0.01] + [1.0, 0.0, 0.0]
    exact_copies(pts)
    point_areas(pts)
    every = np.arange(16) % 2 == 0
    eliminate_cell(pts, 32, 0.2, halo=halo, decided=every, halo_keep=np.arange(16) % 4 == 0, threads=1)
    return time.perf_counter() - t0


def _in_forkserver_main() -> bool:
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "main" and frame.f_globals.get("__name__") == "multiprocessing.forkserver":
            return True
        frame = frame.f_back
    return False


if _in_forkserver_main():
    die_with_parent()
    try:
        logging.getLogger(__name__).debug("kernels warmed up in %.2f s", warm_up() + warm_up_eliminate())
    except Exception as exc:  # noqa: BLE001 - the workers then compile at their first call, and raise there
        logging.getLogger(__name__).warning("kernel warm-up failed in the fork server: %r", exc)
