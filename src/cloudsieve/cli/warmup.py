"""``cloudsieve warmup``: compile every kernel into numba's on-disk cache, once (thin wiring over
:func:`cloudsieve.core.warmup.warm_report`).

For a fresh install, an image or a cluster worker, so that a first run loads its kernels (docs/benchmarks.md,
"Start-up"). The cache: ``__pycache__`` beside the kernels, numba's user cache directory when that is read-only,
or ``NUMBA_CACHE_DIR`` (shareable). With two cores a second process compiles :data:`cloudsieve.core.warmup.SECOND`.
"""

from __future__ import annotations

import argparse
import json
import time

from ._common import add_options, option_values

ORDER = 90


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "warmup",
        help="compile every kernel into numba's cache (after an install, in a container or cluster worker)",
        description=(
            "Compile the numba kernels of cloudsieve into numba's on-disk cache (NUMBA_CACHE_DIR when set, else "
            "__pycache__ beside the modules or numba's user cache directory), so that later runs load them "
            "instead of compiling them: tens of seconds into an empty cache, about a second from a full one. With two "
            "cores or more, two processes compile side by side. Prints each target, the kernels it compiled "
            "and the seconds. Run it once after installing (setup.sh does), "
            "when building a container image, and on cluster workers that do not share a cache directory."
        ),
    )
    add_options(p, "warmup")
    p.add_argument("--json", action="store_true", help="print the targets, kernels and seconds as JSON")
    p.set_defaults(func=run)


def _cache_dir() -> str:
    """Where numba keeps the compiled kernels."""
    from numba.core.config import CACHE_DIR

    return CACHE_DIR or "__pycache__ beside the kernels' modules (numba's user cache directory when read-only)"


def run(args: argparse.Namespace) -> int:
    from ..core.warmup import split_targets, warm_report
    from ..engine import ahead

    targets = option_values(args, "warmup", check=True)["targets"]
    record: dict = {"cache": _cache_dir(), "targets": {}}
    t0 = time.perf_counter()
    mine, theirs = split_targets(targets) if ahead.second_core() else (list(targets), [])
    second = ahead.start_targets(theirs) if theirs else None
    show = None if args.json else _print_target
    try:
        done = warm_report(mine, show)
        if second is not None:
            report = ahead.report_of(second)
            if report is None:  # the second process failed: its targets compile here
                report = warm_report(theirs, show)
            elif show is not None:
                for name, entry in report.items():
                    show(name, entry)
            done.update(report)
    finally:
        ahead.finish(second)
    record["targets"] = {name: done[name] for name in targets}
    record["seconds"] = round(time.perf_counter() - t0, 3)
    if args.json:
        print(json.dumps(record, indent=2))
    else:
        print(f"cloudsieve warmup: {record['seconds']:.2f} s; cache: {record['cache']}")
    return 0


def _print_target(name: str, entry: dict) -> None:
    kernels = entry["compiled"]
    print(f"{name}: {entry['seconds']:.2f} s, {len(kernels)} kernels compiled"
          + ("" if kernels else " (all loaded from the cache)"), flush=True)
    for kernel, s in kernels.items():
        print(f"  {s:7.2f} s  {kernel.removeprefix('cloudsieve.core.kernels.')}")
