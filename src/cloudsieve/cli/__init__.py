"""The ``cloudsieve`` command line: thin wiring over the library.

Each subcommand lives in its own module of this package and exposes
``add_parser(subparsers)``, which registers the subcommand and sets
``func=run``; modules are discovered, so adding a command is adding a file.
``ORDER`` (an int, lower first) in a module sets its place in ``--help``.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import importlib
import logging
import os
import pkgutil
import sys
import threading
import warnings
from typing import NoReturn

from ..errors import CloudsieveError, IncompatibleCloudsWarning

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="cloudsieve",
        description=(
            "Simplify 3D point clouds too large for memory (by default weighted sample elimination to an exact "
            "count; or the entropy rules of Mahdaoui et al. 2017), streaming through a zarr point store, on dask."
        ),
        epilog="Run 'cloudsieve COMMAND --help' for a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"cloudsieve {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    modules = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "add_parser"):
            modules.append(module)
    modules.sort(key=lambda m: (getattr(m, "ORDER", 100), m.__name__))
    for module in modules:
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 2 for a cloudsieve error).

    A closed stdout (``cloudsieve info x.laz | head -1``) ends the command
    quietly with 0, as ``cat`` would stop: the reader has what it wanted.
    """
    try:
        try:
            code = _main(argv)
        finally:  # --help's text too: flushed here, where a closed pipe can still be caught
            sys.stdout.flush()
    except BrokenPipeError:
        _silence_stdout()
        return 0
    return code


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # the subcommand's usage and name, not the top level's (argparse leaves these to the top parser)
        commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
        commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    # shown once, as the log line the library writes beside it (not again as a Python warning)
    warnings.filterwarnings("ignore", category=IncompatibleCloudsWarning)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    # without a terminal, each stage's progress is one INFO line of this logger (--no-progress: none)
    logging.getLogger("cloudsieve.progress").setLevel(min(level, logging.INFO))
    try:
        return int(_with_storage(args) or 0)
    except CloudsieveError as exc:
        from ._common import cli_message, flag_wording

        # a subcommand may set args.wording (run: a pipeline stage's key instead of a flag)
        message = cli_message(exc, getattr(args, "wording", flag_wording))
        print(f"cloudsieve {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        hint = getattr(args, "interrupted_hint", lambda a: "")(args)  # simplify: how to continue
        print(f"cloudsieve {args.command}: interrupted{hint}", file=sys.stderr)
        return 130


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush into a closed pipe raises nothing."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (a test's captured stream)
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def _with_storage(args: argparse.Namespace):
    """The command, with its ``--storage-options`` (checked once, here) in force for every URL it opens."""
    raw = getattr(args, "storage_options", None)
    if raw is None:
        return args.func(args)
    from .. import storage
    from ..params import check

    with storage.using(check("storage_options", raw)):
        return args.func(args)


def run() -> NoReturn:
    """The ``cloudsieve`` command: :func:`main` in a process tuned for one run, which then exits.

    - glibc's malloc takes blocks of up to 32 MiB from its heaps and keeps
      what is freed there (:func:`_keep_freed_memory`): a cell's arrays
      reuse the pages of the cell before instead of faulting in new ones.
    - numpy's large arrays go on ordinary pages, not transparent huge pages
      (:func:`cloudsieve.engine.memory.small_pages_from_here`), here and in
      every process it starts; ``NUMPY_MADVISE_HUGEPAGE=1`` keeps numpy's default.
    - The objects of the imports (numpy, numba, scipy, zarr) are frozen
      (``gc.freeze``): the collector does not walk them, which halves the
      time of a run's collections.
    - What no run uses is skipped (:mod:`cloudsieve.lean_start`): numba
      imports neither scipy nor yaml (without a ``.numba_config.yaml``
      here), its cache loads install none of the compiler's registries,
      laspy imports neither ``requests`` nor ``pyproj``.
    - The exit (:func:`_exit`) ends the threads and runs the exit handlers as
      the interpreter's would, then skips tearing the modules down: every
      file is closed by then.

    Not for a process that goes on (tests call :func:`main`).
    """
    from ..engine.memory import small_pages_from_here
    from ..lean_start import skip_unused_imports

    _keep_freed_memory()
    small_pages_from_here()
    skip_unused_imports()
    gc.freeze()
    _exit(main())


#: glibc's malloc.h
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3


def _keep_freed_memory() -> None:
    """glibc's ``mallopt``: blocks up to 32 MiB (its largest threshold) from the heap, never trimmed below 1 GiB.

    By default a freed block of more than the mmap threshold goes back to the
    system, and the next one faults its pages in again, zeroed by the kernel
    (a few percent of a 10 M-point simplify's CPU). Set so, the run faults
    about a fifth fewer pages. Other C libraries have no ``mallopt``: nothing
    is done.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return
    mallopt(M_MMAP_THRESHOLD, 32 << 20)
    mallopt(M_TRIM_THRESHOLD, 1 << 30)


def _exit(code: int) -> NoReturn:
    """End the process as the interpreter's exit does, less the teardown of its modules (a tenth or more of
    a small run): CPython's own two steps first, threading's shutdown (the thread pools told to stop,
    then every non-daemon thread joined) and the exit handlers (logging's last flush, multiprocessing's
    children, temporary folders). Elsewhere than CPython, the interpreter's exit."""
    shutdown = getattr(threading, "_shutdown", None)
    if shutdown is None:  # pragma: no cover
        sys.exit(code)
    shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(run())
