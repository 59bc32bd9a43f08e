"""``cloudsieve evaluate ORIGINAL SIMPLIFIED``: what simplification cost (thin wiring
over :func:`cloudsieve.evaluate.evaluate`)."""

from __future__ import annotations

import argparse
import functools
import json

from ._common import add_options, option_values

ORDER = 50


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="measure a simplified cloud against its original (point and surface errors, report)",
        description=(
            "Point level: distance from every original point to the simplified cloud (streamed; "
            "or a uniform sample with 95% confidence intervals) and back, mean/RMS/max, symmetric "
            "Hausdorff, absolute and in % of the original's bounding-box diagonal; MPEG pc_error's D1/D2 PSNR "
            "and the Chamfer distance. Surface level "
            "(the paper's): ball-pivoting meshes on tiles, Metro distances both ways, triangle "
            "compactness; by default on random tiles sized for a time budget, their standard errors given, or on "
            "every point. D2 on a uniform sample, its standard error given. The original is streamed; the "
            "simplified cloud is loaded into memory."
        ),
    )
    p.add_argument("original", metavar="ORIGINAL", help="original cloud (LAS/LAZ/COPC/PLY/E57/XYZ file or point store)")
    p.add_argument("simplified", metavar="SIMPLIFIED", help="simplified cloud (file or point store; fits in memory)")
    add_options(p, "evaluate")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the whole report as JSON instead of the summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import progress
    from ..evaluate import evaluate
    from ..evaluate.report import border_per_face, db, fmt, json_ready

    bars = functools.partial(progress.bar, enabled=not args.no_progress)  # bars(stage, total, unit)
    report = evaluate(args.original, args.simplified, **option_values(args, "evaluate"), bars=bars)
    if args.json:
        print(json.dumps(json_ready(report), indent=1))
        return 0
    p = report["point"]
    print(f"original {fmt(report['original']['count'])} points, simplified {fmt(report['simplified']['count'])}, "
          f"diagonal {fmt(report['diagonal'])} ({p['mode']})")
    for name in ("forward", "backward"):
        d = p[name]
        print(f"point {name:8s}: mean {fmt(d['mean'])} ({fmt(d['mean_pct'])}%)  rms {fmt(d['rms'])} "
              f"({fmt(d['rms_pct'])}%)  max {fmt(d['max'])} ({fmt(d['max_pct'])}%)")
    print(f"hausdorff       : {fmt(p['hausdorff'])} ({fmt(p['hausdorff_pct'])}%)")
    ps = report["psnr"]
    for m, label in (("d1", "point-to-point"), ("d2", "point-to-plane")):
        print(f"{m.upper()} PSNR (dB)    : forward {db(ps[m]['forward'])}  backward {db(ps[m]['backward'])}  "
              f"symmetric {db(ps[m]['symmetric'])}  ({label}, peak {fmt(ps['peak'])})")
    for name, n in (ps.get("d2_sample") or {}).items():
        if n and ps["mse"]["d2"][name] > 0:
            print(f"D2 {name:8s}    : on a uniform sample of {fmt(n)} points, PSNR standard error "
                  f"±{ps['d2_se_db'][name]:.3f} dB")
    print(f"chamfer         : {fmt(report['chamfer']['value'])} (mean squared NN distance, both ways summed)")
    s = report.get("surface")
    if s:
        print(f"metro (% diag)  : mean {fmt(s['mean_pct'])}  max {fmt(s['max_pct'])}  rms {fmt(s['rms_pct'])}  "
              f"[{len(s['tiles'])} tile(s)]")
        smp, sp = s.get("sampling") or {}, (s.get("sampling") or {}).get("spread") or {}
        if smp.get("mode") == "budget":
            se = f", standard error of the mean ±{fmt(sp['forward']['mean_pct_se'])}" if sp.get("forward") else ""
            print(f"surface sample  : {len(s['tiles'])} random tiles of <= {fmt(s['tile_points'])} points "
                  f"({100 * smp.get('points_share', 0):.2f}% of the points) sized for {smp['budget']:g} s{se} "
                  "(--surface-full: every point)")
        on = s.get("on_surface")
        if on:
            print(f"metro on surface: mean {fmt(on['mean_pct'])}  max {fmt(on['max_pct'])}  rms {fmt(on['rms_pct'])}  "
                  f"({100 * on['excluded_share']:.2f}% of the backward samples face a hole of the original's mesh)")
        ref = (s.get("reference") or {}).get("simplified") or {}
        if ref.get("forward"):
            print(f"metro vs mesh   : mean {fmt(ref['mean_pct'])}  max {fmt(ref['max_pct'])}  rms "
                  f"{fmt(ref['rms_pct'])}  (simplified mesh vs the reference mesh; original mesh: mean "
                  f"{fmt(s['reference']['original'].get('mean_pct'))})")
        print(f"compactness>=0.6: original {100 * s['original']['compact_share']:.2f}%  "
              f"simplified {100 * s['simplified']['compact_share']:.2f}%  "
              f"(simplified mesh {fmt(s['vertices'])} vertices, {fmt(s['faces'])} faces)")
        print(f"border edges    : original {border_per_face(s['original'])} per face, simplified "
              f"{border_per_face(s['simplified'])} (holes of the ball-pivoting meshes)")
    if args.report_dir:
        print(f"report: {report['files']['html']} (and report.md, report.json)")
    return 0
