"""The ``cloudsieve`` command line: thin wiring over the library.

Each subcommand is a module of this package exposing ``add_parser(subparsers)``
(which sets ``func=run``); modules are discovered. ``ORDER`` (lower first)
sets a module's place in ``--help``.
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
    """Run the CLI; returns the exit code (0 ok, 2 for a cloudsieve error); a closed stdout ends it quietly with 0."""
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
    glibc's malloc keeps freed blocks (:func:`_keep_freed_memory`); numpy's large arrays avoid transparent huge
    pages (:func:`cloudsieve.engine.memory.small_pages_from_here`; ``NUMPY_MADVISE_HUGEPAGE=1`` keeps numpy's
    default); the imports' objects are frozen (``gc.freeze``); unused imports are skipped
    (:mod:`cloudsieve.lean_start`); :func:`_exit` skips the module teardown. Not for a process that goes on (tests
    call :func:`main`)."""
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
    """glibc's ``mallopt``: blocks up to 32 MiB from the heap, never trimmed below 1 GiB (fewer page faults); a no-op
    elsewhere."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return
    mallopt(M_MMAP_THRESHOLD, 32 << 20)
    mallopt(M_TRIM_THRESHOLD, 1 << 30)


def _exit(code: int) -> NoReturn:
    """End the process as the interpreter's exit does (threading's shutdown, the exit handlers), less the
    teardown of its modules; elsewhere than CPython, the interpreter's exit."""
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
