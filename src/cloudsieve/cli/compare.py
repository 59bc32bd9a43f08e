"""``cloudsieve compare SRC``: entropy simplification vs baselines at the same count
(thin wiring over :func:`cloudsieve.evaluate.compare`)."""

from __future__ import annotations

import argparse

from ._common import positive_int as _positive_int

ORDER = 60


def _ratio(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {value}")
    return value


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "compare",
        help="compare KM/FCM entropy simplification with baselines at the same output count",
        description=(
            "Run each method on SRC to the same number of kept points, evaluate each (point errors, "
            "ball-pivoting meshes, Metro, compactness) and print one Markdown table. Methods: km, fcm "
            "(entropy), random, voxel (the point nearest each voxel centroid), poisson (Poisson-disk "
            "subsample), fps (farthest point; small clouds only). SRC is loaded into memory: compare "
            "is for choosing a method on a model, a sample or a tile."
        ),
    )
    p.add_argument("src", metavar="SRC", help="cloud (LAS/LAZ/COPC/PLY/E57/XYZ file or point store), loaded into memory")
    p.add_argument("--methods", default="km,fcm,random,voxel,poisson,fps", metavar="LIST",
                   help="comma-separated methods (default km,fcm,random,voxel,poisson,fps)")
    p.add_argument("--rule", default="iterative", metavar="RULES",
                   help="entropy rule(s), comma-separated: iterative (default), target, coverage, threshold")
    p.add_argument("--threshold", type=float, default=1e-3, metavar="S", help="entropy-change threshold S (rule threshold)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--ratio", type=_ratio, metavar="R", help="keep this share of the points")
    g.add_argument("--count", type=_positive_int, metavar="N", help="keep this many points")
    p.add_argument("--cluster-size", type=_positive_int, default=400, metavar="M", help="points per small cluster (default 400)")
    p.add_argument("--report", metavar="DIR", help="write report.md, report.json, plots and one report per method into DIR")
    p.add_argument("--tiles", type=_positive_int, default=4, metavar="T", help="surface tiles (default 4)")
    p.add_argument("--tile-points", type=_positive_int, default=200_000, metavar="M", help="at most M points per tile (default 200000)")
    p.add_argument("--no-surface", action="store_true", help="point level only (no meshes)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import progress
    from ..evaluate import compare

    methods = [m for m in args.methods.split(",") if m.strip()]
    with progress.bar("methods", len(methods), unit="method", enabled=not args.no_progress) as tick:
        result = compare(
            args.src, methods=methods, rule=args.rule, ratio=args.ratio, count=args.count, report_dir=args.report,
            surface=not args.no_surface, tiles=args.tiles, tile_points=args.tile_points, seed=args.seed,
            progress=tick, threshold=args.threshold, cluster_size=args.cluster_size,
        )
    print(result["markdown"])
    return 0
