"""``cloudsieve simplify SRC DST``: the out-of-core simplification (thin wiring over
:func:`cloudsieve.engine.simplify`)."""

from __future__ import annotations

import argparse
import functools
import json
import sys

from ._common import add_options, option_values

ORDER = 40


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "simplify",
        help="simplify a point cloud of any size (out of core, on dask)",
        description=(
            "Simplify SRC into DST out of core: the cloud is ingested into a zarr point store (the work store), "
            "cut into coarse cells (one dask task each), each cell pruned by the rule, and the kept points "
            "written with every attribute and the header. A LAS/LAZ/COPC or PLY input of at most 10,000,000 "
            "points runs in memory instead, without the store, to the same bytes, when the rule is eliminate "
            "and no scheduler, worker count, memory limit, store, resume or tiles are asked for. The default "
            "rule, eliminate (weighted sample "
            "elimination: the most crowded point goes first; no clusters, no entropy), keeps exactly --ratio R "
            "or --count N points. --threshold S alone runs the paper's rule (Mahdaoui et al. 2017: small "
            "K-means/FCM clusters, each point scored by how much it changes the entropy of its cluster's "
            "density, the points below S dropped); --rule picks any rule. Same seed, same bytes, on any "
            "scheduler. Every option, SRC, DST's format and folder, the work store and the scheduler are "
            "checked before any work starts."
        ),
    )
    p.add_argument("src", metavar="SRC", help="input file (LAS/LAZ/COPC/PLY/E57/XYZ), a point store, or LAS/LAZ/COPC "
                   "files as one cloud: a quoted glob ('tiles/*.laz'), a directory, a list file (.lst: one path per "
                   "line, relative to the list's folder) or a VPC (.vpc)")
    p.add_argument("dst", metavar="DST", help="output file (LAS/LAZ/COPC (.copc.laz)/PLY/XYZ, by extension or "
                   "--format), or with --tile-size a folder of LAZ tiles and index.vpc")
    add_options(p, "simplify")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run, interrupted_hint=interrupted_hint)


def interrupted_hint(args: argparse.Namespace) -> str:
    """What to say after Ctrl-C: the work store survives (unless the run had none yet, or ran in memory)."""
    import os

    from ..engine.workstore import work_store_path
    from ..store import is_store

    path = work_store_path(args.src, args.dst, args.store, is_store(args.src))
    if "://" in path or os.path.exists(path):
        return "; the work store is kept: run the same command again (or add --resume) to continue"
    return "; nothing to resume: run the same command again"


def run(args: argparse.Namespace) -> int:
    from .. import progress
    from ..engine import simplify

    bars = functools.partial(progress.bar, enabled=not args.no_progress)  # bars(stage, total, unit)
    def notify(message: str) -> None:
        print(message, file=sys.stderr)

    # the API validates every option, once; the error's words become the command line's (cli_message)
    summary = simplify(args.src, args.dst, **option_values(args, "simplify"), bars=bars, notify=notify)
    if args.json:
        record = summary.to_dict()
        record["store"] = record["store"] or None  # null, not "", when the work store was removed
        print(json.dumps(record, indent=2))
    else:
        print(f"cloudsieve simplify: {args.src} -> {args.dst}")
        print(summary)
    return 0
