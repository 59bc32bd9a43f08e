"""The ``cloudsieve`` command line: thin wiring over the library.

Each subcommand lives in its own module of this package and exposes
``add_parser(subparsers)``, which registers the subcommand and sets
``func=run``; modules are discovered, so adding a command is adding a file.
``ORDER`` (an int, lower first) in a module sets its place in ``--help``.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import logging
import os
import pkgutil
import sys
import warnings

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
        return int(args.func(args) or 0)
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


def run() -> int:
    """The ``cloudsieve`` command (the process exits next, with the code returned): :func:`main`.

    The objects of the imports (the package imports numpy, numba, scipy and
    zarr) are frozen first (``gc.freeze``): the collector no longer walks
    them, and the collections of a 10 M-point simplify took 0.12 s instead
    of 0.23-0.25 s. The objects left at the end are frozen too: the
    interpreter's exit skips collecting them (0.27 s after a 10 M-point
    simplify, 0.06 s frozen). Every file is closed by then, and the exit
    handlers still run. Not for a process that goes on (tests call
    :func:`main`).
    """
    gc.freeze()
    code = main()
    gc.freeze()
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(run())
