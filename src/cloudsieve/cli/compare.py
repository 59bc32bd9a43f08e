"""``cloudsieve compare SRC``: entropy simplification vs baselines at the same count
(thin wiring over :func:`cloudsieve.evaluate.compare`: its options validated here, once, then
:func:`cloudsieve.evaluate.compare.run_compare`)."""

from __future__ import annotations

import argparse

from ._common import add_options, option_values

ORDER = 60


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "compare",
        help="compare entropy simplification (default rule eliminate) with baselines at the same output count",
        description=(
            "Run each method on SRC to the same number of kept points, evaluate each (point errors, "
            "ball-pivoting meshes, Metro, compactness) and print one Markdown table. Methods: km, fcm "
            "(entropy), random, voxel (the point nearest each voxel centroid), poisson (Poisson-disk "
            "subsample), fps (farthest point; small clouds only). SRC is loaded into memory: compare "
            "is for choosing a method on a model, a sample or a tile. The default rule, eliminate, runs once "
            "(it uses no clusters) and needs --ratio or --count; --rule iterative (or --threshold S alone: "
            "threshold) runs the paper's rules once per entropy method."
        ),
    )
    p.add_argument("src", metavar="SRC", help="cloud (LAS/LAZ/COPC/PLY/E57/XYZ file or point store), loaded into memory")
    add_options(p, "compare")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import params, progress
    from ..evaluate.compare import compare_runs, run_compare

    # validated once, here: the rule resolved sizes the bar, and the API's run takes the options as they are
    opts = params.options("compare", option_values(args, "compare"), caller="cloudsieve compare")
    runs = len(compare_runs(opts.methods, opts.rule))
    with progress.bar("methods", runs, unit="method", enabled=not args.no_progress) as tick:
        result = run_compare(args.src, opts, progress=tick)
    print(result["markdown"])
    return 0
