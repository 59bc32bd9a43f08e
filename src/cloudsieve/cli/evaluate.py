"""``cloudsieve evaluate ORIGINAL SIMPLIFIED``: what simplification cost (thin wiring
over :func:`cloudsieve.evaluate.evaluate`)."""

from __future__ import annotations

import argparse
import json
import sys

from ..store import DEFAULT_CHUNK_SIZE
from ._common import positive_int as _positive_int

ORDER = 50


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="measure a simplified cloud against its original (point and surface errors, report)",
        description=(
            "Point level: distance from every original point to the simplified cloud (streamed; "
            "or a uniform sample with 95% confidence intervals) and back, mean/RMS/max, symmetric "
            "Hausdorff, absolute and in % of the original's bounding-box diagonal. Surface level "
            "(the paper's): ball-pivoting meshes on T tiles, Metro distances both ways, triangle "
            "compactness. The original is streamed; the simplified cloud is loaded into memory."
        ),
    )
    p.add_argument("original", metavar="ORIGINAL", help="original cloud (LAS/LAZ/COPC/PLY/E57/XYZ file or point store)")
    p.add_argument("simplified", metavar="SIMPLIFIED", help="simplified cloud (file or point store; fits in memory)")
    p.add_argument("--sample", type=_positive_int, metavar="N", help="evaluate a uniform sample of N points per direction (95%% CI)")
    p.add_argument("--tiles", type=_positive_int, default=4, metavar="T", help="surface tiles (default 4)")
    p.add_argument("--tile-points", type=_positive_int, default=200_000, metavar="M",
                   help="at most M original points per tile; the whole cloud when it has at most M (default 200000)")
    p.add_argument("--no-surface", action="store_true", help="point level only (no meshes)")
    p.add_argument("--report", metavar="DIR", help="write report.json, report.md, plots and errors.ply into DIR")
    p.add_argument("--subset", action="store_true", help="the simplified cloud must be a subset of the original (error otherwise)")
    p.add_argument("--force", action="store_true", help="warn instead of failing on different CRS or units")
    p.add_argument("--seed", type=int, default=0, help="seed of the samples and tiles (default 0)")
    p.add_argument("--chunk-size", type=_positive_int, default=DEFAULT_CHUNK_SIZE, metavar="POINTS", help="points per chunk of the original")
    p.add_argument("--error-points", type=int, default=2_000_000, metavar="N",
                   help="at most N points in errors.ply (uniform sample; default 2000000)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the whole report as JSON instead of the summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import progress
    from ..evaluate import evaluate
    from ..evaluate.report import fmt, json_ready

    with progress.bar("point errors", None, enabled=not args.no_progress) as tick:
        report = evaluate(
            args.original, args.simplified, sample=args.sample, surface=not args.no_surface, tiles=args.tiles,
            tile_points=args.tile_points, seed=args.seed, subset=args.subset, strict=not args.force,
            report_dir=args.report, error_points=args.error_points, chunk_size=args.chunk_size, progress=tick,
        )
    if args.json:
        print(json.dumps(json_ready(report), indent=1))
        return 0
    for w in report["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    p = report["point"]
    print(f"original {fmt(report['original']['count'])} points, simplified {fmt(report['simplified']['count'])}, "
          f"diagonal {fmt(report['diagonal'])} ({p['mode']})")
    for name in ("forward", "backward"):
        d = p[name]
        print(f"point {name:8s}: mean {fmt(d['mean'])} ({fmt(d['mean_pct'])}%)  rms {fmt(d['rms'])} "
              f"({fmt(d['rms_pct'])}%)  max {fmt(d['max'])} ({fmt(d['max_pct'])}%)")
    print(f"hausdorff       : {fmt(p['hausdorff'])} ({fmt(p['hausdorff_pct'])}%)")
    s = report.get("surface")
    if s:
        print(f"metro (% diag)  : mean {fmt(s['mean_pct'])}  max {fmt(s['max_pct'])}  rms {fmt(s['rms_pct'])}  "
              f"[{len(s['tiles'])} tile(s)]")
        print(f"compactness>=0.6: original {100 * s['original']['compact_share']:.2f}%  "
              f"simplified {100 * s['simplified']['compact_share']:.2f}%  "
              f"(simplified mesh {fmt(s['vertices'])} vertices, {fmt(s['faces'])} faces)")
    if args.report:
        print(f"report: {args.report}/report.md")
    return 0
