"""Benchmark the evaluation: point level exact vs sampled, surface level on tiles.

    .venv/bin/python benchmarks/evaluate.py                       # 10 M original / 5 M simplified
    .venv/bin/python benchmarks/evaluate.py --sizes 1e6,5e5       # a small run
    .venv/bin/python benchmarks/evaluate.py --original scan.laz --ratio 0.5   # a real file (decode included)
    .venv/bin/python benchmarks/evaluate.py --end-to-end 10e6     # the command line, as a user runs it

``--end-to-end N`` makes an N-point LAZ scan (benchmarks/make_scan.py, kept
in ``--workdir``), simplifies it at 50% (``cloudsieve simplify --ratio
0.5``), runs ``cloudsieve evaluate ORIGINAL SIMPLIFIED --report DIR`` with
default options, and prints its wall time by level (report.json's timing),
the peak resident memory of the evaluate process and its children (psutil,
sampled every 0.1 s), report.html's size and its load time in headless
Chromium; the load average (``os.getloadavg()``) beside each figure. The
load time is measured three ways, three runs each: the page's own time from
navigation to its first drawn frame (the viewer writes it into
``document.body.dataset.renderMs``, read back with ``--dump-dom``), the
wall time of ``chromium --headless --dump-dom`` on the page, and the same
on ``about:blank`` (the browser's start alone). Goals: evaluation <= 2
minutes on 2 cores, report.html < 15 MB opening in < 5 s.

The original is built in memory by tiling the real aerial survey
``autzen_trim.laz`` (110,000 points, ../shared/data) on a grid, each tile
shifted and jittered by a few centimetres (the layout of
benchmarks/make_scan.py: chunks are spatially coherent, as in real LAS
files); a synthetic terrain when the file is absent. The simplified cloud is
a seeded uniform subset (the evaluation's cost does not depend on which
points are kept, only on how many; a subset is the usual case). Prints a
Markdown table. The goal: point level exact >= 2 M original points/s on 2
cores.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
AUTZEN = ROOT.parent / "shared" / "data" / "autzen_trim.laz"


def make_cloud(n: int, seed: int = 0) -> np.ndarray:
    """n points (n, 3) float64: tiles of autzen_trim shifted on a grid, jittered."""
    rng = np.random.default_rng(seed)
    if AUTZEN.is_file():
        import laspy

        base = np.asarray(laspy.read(AUTZEN).xyz, dtype=np.float64)
    else:  # synthetic terrain tile, 1200 x 600 m
        u = rng.random((110_000, 2)) * [1200, 600]
        base = np.c_[u, 10 * np.sin(u[:, 0] / 90) + 5 * np.cos(u[:, 1] / 70)]
    base -= base.min(axis=0)
    span = base.max(axis=0) - base.min(axis=0)
    tiles = -(-n // len(base))
    side = int(np.ceil(np.sqrt(tiles)))
    out = np.empty((tiles * len(base), 3))
    for t in range(tiles):
        i, j = divmod(t, side)
        out[t * len(base) : (t + 1) * len(base)] = base + [i * span[0], j * span[1], 0] + rng.normal(0, 0.03, base.shape)
    return out[:n]


def _time(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="10e6,5e6", help="ORIGINAL,SIMPLIFIED point counts (default 10e6,5e6)")
    ap.add_argument("--original", help="evaluate against this file instead (streamed through the IO layer)")
    ap.add_argument("--ratio", type=float, default=0.5, help="kept share with --original (default 0.5)")
    ap.add_argument("--sample", type=int, default=100_000, help="sampled mode: points per direction (default 100000)")
    ap.add_argument("--tiles", type=int, default=4)
    ap.add_argument("--tile-points", type=int, default=200_000)
    ap.add_argument("--no-surface", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--end-to-end", type=float, metavar="N",
                    help="the command line on an N-point scan: make_scan, simplify 50%%, evaluate --report, Chromium")
    ap.add_argument("--workdir", default="/tmp/cloudsieve-bench-evaluate", help="--end-to-end's files")
    args = ap.parse_args(argv)
    if args.end_to_end:
        from evaluate_cli import end_to_end

        return end_to_end(int(args.end_to_end), Path(args.workdir))

    from cloudsieve.evaluate.points import PointLevel, point_errors
    from cloudsieve.evaluate.surface import TilePlan, surface_errors

    rng = np.random.default_rng(args.seed + 1)
    if args.original:
        from cloudsieve.io import read_cloud

        original = args.original
        xyz, _ = read_cloud(original)  # only to draw the simplified subset
        n = len(xyz)
        simplified = xyz[np.sort(rng.choice(n, int(args.ratio * n), replace=False))]
        del xyz
        label = os.path.basename(original)
    else:
        n, m = (int(float(v)) for v in args.sizes.split(","))
        t_gen, original = _time(lambda: make_cloud(n, args.seed))
        simplified = original[np.sort(rng.choice(n, m, replace=False))]
        label = "in memory (tiled autzen_trim)"
        print(f"generated {n:,} points in {t_gen:.1f} s", file=sys.stderr)
    m = len(simplified)
    print(f"## Evaluation benchmark: {label}, {os.cpu_count()} cores\n")
    print("| stage | original / simplified points | time (s) | original points/s | result |")
    print("|---|---:|---:|---:|---|", flush=True)

    def row(stage, size, t, rate, res):  # printed as soon as measured
        shown = f"{rate / 1e6:.2f} M" if rate >= 1e5 else f"{rate / 1e3:.1f} k"
        print(f"| {stage} | {size} | {t:.2f} | {shown} | {res} |", flush=True)

    t, r = _time(lambda: point_errors(original, simplified))
    row("point level, exact (both directions)", f"{n:,} / {m:,}", t, n / t,
        f"mean {r['forward']['mean']:.4g}, RMS {r['forward']['rms']:.4g}, max {r['forward']['max']:.4g}")
    exact = r
    t, r = _time(lambda: point_errors(original, simplified, PointLevel(sample=args.sample, seed=args.seed)))
    ci = r["forward"]["ci"]["mean"]
    inside = ci[0] <= exact["forward"]["mean"] <= ci[1]
    row(f"point level, sampled ({args.sample:,} per direction)", f"{n:,} / {m:,}", t, n / t,
        f"mean {r['forward']['mean']:.4g} CI [{ci[0]:.4g}, {ci[1]:.4g}] "
        f"({'contains' if inside else 'MISSES'} the exact mean)")
    if not args.no_surface:
        t, s = _time(lambda: surface_errors(original, simplified, TilePlan(tiles=args.tiles,
                                                                           tile_points=args.tile_points, seed=args.seed),
                                            diagonal=exact["diagonal"]))
        pts = sum(x["points_original"] for x in s["tiles"])
        row(f"surface level, {len(s['tiles'])} tiles of <= {args.tile_points:,} points",
            f"{pts:,} / {sum(x['points_simplified'] for x in s['tiles']):,}", t, pts / t,
            f"Metro mean {s['mean_pct']:.4g}% max {s['max_pct']:.4g}% RMS {s['rms_pct']:.4g}%, "
            f"c>=0.6 {100 * s['original']['compact_share']:.1f}% -> {100 * s['compact_share']:.1f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
