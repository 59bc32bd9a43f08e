"""A second core compiles ahead: the first run into an empty numba cache.

numba compiles each kernel in the process that first calls it, one at a
time. When the cache lacks kernels of :data:`cloudsieve.core.warmup.AHEAD`,
:func:`start` runs ``python -m cloudsieve.core.warmup`` beside the run, which
later loads them from the cache (or compiles them itself: the same code).
``cloudsieve warmup`` uses it for whole targets (:func:`start_targets`). The
process dies with the run (:func:`cloudsieve.lifeline.die_with_parent`, :func:`finish`).
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

#: the second process's module: the kernels and warm-up alone, without the engine's slow imports
COMPILER = "cloudsieve.core.warmup"


def second_core() -> bool:
    """Whether a second process can compile beside this one (two cores or more)."""
    return (os.cpu_count() or 1) >= 2


def start(targets: Iterable[str]) -> subprocess.Popen | None:
    """Start compiling ahead the parts of *targets* numba's cache lacks; None with nothing to do or one core."""
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
    """The report (:func:`cloudsieve.core.warmup.warm_report`) of a finished :func:`start_targets` process, None on failure."""
    out, _ = proc.communicate()
    if proc.returncode != 0:
        return None
    return json.loads(out)


def finish(proc: subprocess.Popen | None) -> None:
    """End the process :func:`start` started, if any (numba renames cache files into place: none half written)."""
    if proc is not None:
        if proc.poll() is None:
            proc.terminate()
        proc.wait()
