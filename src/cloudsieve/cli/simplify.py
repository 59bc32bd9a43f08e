"""``cloudsieve simplify SRC DST``: the out-of-core simplification (thin wiring over
:func:`cloudsieve.engine.simplify`)."""

from __future__ import annotations

import argparse
import json
import sys

from ..store import DEFAULT_CHUNK_SIZE
from ._common import positive_int as _positive_int

ORDER = 40


def _memory(text: str) -> str | int:
    return int(text) if text.isdigit() else text


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "simplify",
        help="simplify a point cloud of any size (out of core, on dask)",
        description=(
            "Simplify SRC into DST by entropy estimation (Mahdaoui et al. 2017): the cloud is "
            "ingested into a zarr point store, cut into coarse cells (dask tasks), each cell "
            "refined into small KM/FCM clusters, scored and pruned, and the kept points written "
            "with every attribute. Same seed, same bytes, on any scheduler."
        ),
    )
    p.add_argument("src", metavar="SRC", help="input file (LAS/LAZ/COPC/PLY/E57/XYZ) or point store")
    p.add_argument("dst", metavar="DST", help="output file (LAS/LAZ/PLY/XYZ, by extension)")
    p.add_argument("--method", choices=["km", "fcm"], default="fcm", help="refinement into small clusters (default fcm)")
    p.add_argument(
        "--rule", choices=["iterative", "threshold", "target", "coverage"], default="iterative",
        help="pruning rule (default iterative; target and coverage need --ratio or --count)"
    )
    p.add_argument("--threshold", type=float, default=1e-3, metavar="S", help="entropy-change threshold S (default 0.001)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--ratio", type=float, metavar="R", help="keep this share of the points (0 < R <= 1), within 1%%")
    g.add_argument("--count", type=_positive_int, metavar="N", help="keep this many points, within 1%%")
    p.add_argument("--cluster-size", type=_positive_int, default=400, metavar="M", help="points per small cluster (default 400)")
    p.add_argument(
        "--cell-size", type=_positive_int, default=100_000, metavar="POINTS",
        help="points per cell, i.e. per task; bounds a task's memory (default 100000)"
    )
    p.add_argument(
        "--scheduler",
        metavar="SCHED",
        help="sync, threads, processes or a dask.distributed address tcp://host:port (default: local, no set-up)",
    )
    p.add_argument("--workers", type=_positive_int, metavar="N", help="local workers (default: all cores)")
    p.add_argument("--memory-limit", type=_memory, metavar="SIZE", help="memory cap per worker, e.g. 1GB (local cluster)")
    p.add_argument("--store", metavar="PATH", help="work store (path or fsspec URL); default DST.cloudsieve.zarr, removed on success")
    p.add_argument(
        "--halo-context",
        action="store_true",
        help="use each cell's halo (and the whole cell) as density context instead of the small cluster alone",
    )
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--resume", action="store_true", help="continue a crashed run from its work store")
    p.add_argument("--overwrite", action="store_true", help="replace DST and discard an incompatible work store")
    p.add_argument("--format", help="output format (default: by DST's extension)")
    p.add_argument("--chunk-size", type=_positive_int, default=DEFAULT_CHUNK_SIZE, metavar="POINTS", help="points per store chunk")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import progress
    from ..engine import simplify

    def bars(stage, total, unit):
        return progress.bar(stage, total, unit=unit, enabled=not args.no_progress)

    def notify(message: str) -> None:
        print(message, file=sys.stderr)

    summary = simplify(
        args.src,
        args.dst,
        method=args.method,
        rule=args.rule,
        threshold=args.threshold,
        ratio=args.ratio,
        count=args.count,
        cluster_size=args.cluster_size,
        cell_size=args.cell_size,
        scheduler=args.scheduler,
        workers=args.workers,
        memory_limit=args.memory_limit,
        store=args.store,
        seed=args.seed,
        resume=args.resume,
        overwrite=args.overwrite,
        format=args.format,
        chunk_size=args.chunk_size,
        context=args.halo_context,
        bars=bars,
        notify=notify,
    )
    if args.json:
        print(json.dumps(summary.to_dict(), indent=2))
    else:
        print(f"cloudsieve simplify: {args.src} -> {args.dst}")
        print(summary)
    return 0
