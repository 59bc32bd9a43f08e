"""A second core compiles ahead: the first run into an empty numba cache.

numba compiles a kernel in the process that first calls it, one kernel at a
time, so a run into an empty cache (an install without ``cloudsieve warmup``,
a new container or cluster worker) compiles on one core while the other
waits. When the run's warm-up targets have a part a second process can
compile from inputs of the real calls' types
(:data:`cloudsieve.core.warmup.AHEAD`: the kernels the default rule reaches
last, its elimination loop among them) and numba's cache does not hold it,
:func:`start` runs ``python -m cloudsieve.core.warmup TARGET...`` beside
the run. The run compiles the kernels that come first (the copies', the
grid's, the packing's, the k-d cut's, the neighbour lists'); reaching the
others, it loads them from the cache (numba writes each file under a
temporary name and renames it), or compiles one itself if the other process
has not finished it. Either way the code is the same, so the results are
too. A cold run then uses both cores where numba alone compiles on one: it
takes about three fifths as long.

``cloudsieve warmup`` uses the same process for whole targets
(:func:`start_targets`, :data:`cloudsieve.core.warmup.SECOND`): it prints
what it compiled as JSON, which the command merges into its report.

The process dies with the run (:func:`cloudsieve.lifeline.die_with_parent`), and
:func:`finish` ends it with the run, so none outlives the command.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from collections.abc import Iterable

__all__ = ["second_core", "start", "start_targets", "report_of", "finish"]

logger = logging.getLogger(__name__)

#: the second process's module: it imports the kernels and the warm-up alone, not the engine (whose
#: zarr and dask imports would delay its first compilation)
COMPILER = "cloudsieve.core.warmup"


def second_core() -> bool:
    """Whether a second process can compile beside this one (two cores or more)."""
    return (os.cpu_count() or 1) >= 2


def start(targets: Iterable[str]) -> subprocess.Popen | None:
    """Start compiling ahead the parts of *targets* numba's cache lacks; None when there is none to compile
    or one core only."""
    from ..core.warmup import ahead_parts

    parts = ahead_parts(targets)
    if not parts or not second_core():
        return None
    proc = subprocess.Popen([sys.executable, "-m", COMPILER, *parts], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    logger.info("numba's cache lacks the kernels of %s: process %d compiles part of them ahead",
                ", ".join(parts), proc.pid)
    return proc


def start_targets(targets: Iterable[str]) -> subprocess.Popen:
    """Start compiling the warm-up *targets* whole in a second process; :func:`report_of` reads its report."""
    return subprocess.Popen([sys.executable, "-m", COMPILER, "--targets", *targets], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, text=True)


def report_of(proc: subprocess.Popen) -> dict | None:
    """The report (:func:`cloudsieve.core.warmup.warm_report`) of a :func:`start_targets` process once it
    ends; None when it failed (its error went to this process's stderr)."""
    out, _ = proc.communicate()
    if proc.returncode != 0:
        return None
    return json.loads(out)


def finish(proc: subprocess.Popen | None) -> None:
    """End the process :func:`start` started, if any: the run is over (an interrupted or failed one too),
    so it stops now if it has not finished (numba renames each cache file into place when complete:
    nothing is left half written)."""
    if proc is not None:
        if proc.poll() is None:
            proc.terminate()
        proc.wait()
