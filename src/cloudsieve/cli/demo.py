"""``cloudsieve demo``: the main job end to end on a built-in example scan."""

from __future__ import annotations

import argparse
import os
import time

from ._common import add_options, option_values, positive_int

ORDER = 80


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo",
        help="simplify and evaluate a generated example scan (no data needed)",
        description=(
            "Generate an example aerial scan (terrain, buildings, trees; LAS 1.4 point format 7 "
            "with intensity, classification, GPS time, RGB), simplify it on dask (default: rule "
            "eliminate, --ratio 0.5), and evaluate what was lost. Writes everything into --out."
        ),
    )
    p.add_argument("--points", type=positive_int, default=200_000, help="points in the example scan (default: 200000)")
    p.add_argument("--out", default="cloudsieve-demo", help="output folder (default: ./cloudsieve-demo)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an existing, non-empty --out folder (its demo files are replaced, others kept)")
    add_options(p, "simplify", ["method", "rule", "ratio", "scheduler", "seed"], defaults={"method": "km", "ratio": 0.5},
                helps={"rule": "pruning rule (default: eliminate, weighted sample elimination, exactly --ratio of the "
                               "points); iterative, target and coverage also keep about --ratio"})
    p.add_argument("--no-progress", action="store_true", help="no progress bars (nor, without a terminal, the log "
                                                                 "line of each stage)")
    p.set_defaults(func=run)


def _prepare_folder(out: str, overwrite: bool) -> None:
    """Create the output folder; refuse a non-empty one unless *overwrite*, and a path that is not a folder."""
    from ..errors import DestinationExistsError, DestinationNotWritableError

    if os.path.lexists(out) and not os.path.isdir(out):
        raise DestinationNotWritableError(f"cannot write into {out}: it is not a folder")
    if os.path.isdir(out) and os.listdir(out) and not overwrite:
        raise DestinationExistsError(
            f"{out} exists and is not empty ({len(os.listdir(out))} entries); pass --overwrite to write the demo "
            f"into it anyway (its demo files are replaced, others kept), or choose another --out")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise DestinationNotWritableError(f"cannot create {out}: {exc.strerror or exc}") from None


def run(args: argparse.Namespace) -> int:
    from ..core.rules import get as get_rule
    from ..engine.simplify import run_simplify
    from ..evaluate import evaluate
    from ..params import validate
    from functools import partial

    from ..progress import bar
    from ..synthetic import write_scene_laz

    bar = partial(bar, enabled=not args.no_progress)
    # validated once, before anything is written; demo's --overwrite is about its folder (its files are replaced)
    options = validate("simplify", {**option_values(args, "simplify"), "overwrite": True})
    _prepare_folder(args.out, args.overwrite)
    src = os.path.join(args.out, "scene.laz")
    dst = os.path.join(args.out, "scene-simplified.laz")
    report = os.path.join(args.out, "report")
    t0 = time.perf_counter()
    write_scene_laz(src, args.points, seed=args.seed)
    print(f"1/3 wrote example scan {src}: {args.points:,} points ({time.perf_counter() - t0:.1f} s)")

    t0 = time.perf_counter()
    summary = run_simplify(src, dst, options, bars=bar, notify=print)
    print(
        f"2/3 simplified -> {dst}: kept {summary.kept:,} of {summary.points_in:,} points "
        f"({time.perf_counter() - t0:.1f} s, rule {options['rule']}"
        + (f", method {options['method']})" if get_rule(options["rule"]).clusters else ")")
    )

    t0 = time.perf_counter()
    result = evaluate(src, dst, report_dir=report, tiles=2, tile_points=50_000, bars=bar)
    fwd = result["point"]["forward"]
    surf = result.get("surface") or {}
    print(
        f"3/3 evaluated ({time.perf_counter() - t0:.1f} s): point error original->simplified "
        f"mean {fwd['mean_pct']:.4f}%, RMS {fwd['rms_pct']:.4f}%, max {fwd['max_pct']:.4f}% of the diagonal"
    )
    if surf.get("rms_pct") is not None:
        print(
            f"    surface (Metro, ball-pivoting meshes): mean {surf['mean_pct']:.4f}%, "
            f"RMS {surf['rms_pct']:.4f}%, max {surf['max_pct']:.4f}%; "
            f"compact triangles {100 * surf['compact_share']:.1f}%"
        )
    print(f"    report: {os.path.join(report, 'report.md')}")
    return 0
