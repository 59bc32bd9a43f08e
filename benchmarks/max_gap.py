"""``--max-gap D`` as the engine runs it: the points it adds back and what it costs.

Run: ``.venv/bin/python benchmarks/max_gap.py [--ratios 0.5,0.2,0.1] [FILES...]``

For every scan and share kept (c points): ``cloudsieve.simplify`` at c, the
median distance from a dropped point to its nearest kept point (as in
``gap.py``'s second table), then ``cloudsieve.simplify(..., max_gap=D)`` for
D = 1.5, 2 and 3 times that median: the points the engine's fill adds back
(per cell, colour by colour: :mod:`cloudsieve.engine.gap`), beside those of
``gap.py``'s greedy farthest-point fill on the whole cloud after the same
rule; the largest gap checked by a k-d tree on the output (never above D);
the run's seconds against the run without the bound. Default cell size, so
every shared scan is one cell here; ``--cell-size`` splits them.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import cloudsieve
from cloudsieve.io import read_cloud

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gap import DATA, MULTIPLES, SCANS, greedy_fill  # noqa: E402


def run(src: Path, dst: Path, **options) -> tuple[np.ndarray, object, float]:
    t = time.perf_counter()
    summary = cloudsieve.simplify(src, dst, overwrite=True, **options)
    return np.asarray(read_cloud(str(dst))[0], dtype=np.float64), summary, time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", default=SCANS)
    ap.add_argument("--ratios", default="0.5,0.2,0.1")
    ap.add_argument("--cell-size", type=int, default=200_000)
    a = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    warnings.filterwarnings("ignore")
    greedy_fill(np.random.default_rng(0).random((64, 3)), np.arange(8), add=4)  # compiled before any timing
    head = "".join(f" {m:g}x: engine / greedy | max / D |" for m in MULTIPLES)
    print("| scan | kept | cells | median % |" + head + " seconds plain / with D | load |")
    print("|---|---|---:|---:|" + "---|---:|" * len(MULTIPLES) + "---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.files:
            src = Path(name) if Path(name).is_file() else DATA / name
            points = np.asarray(read_cloud(str(src))[0], dtype=np.float64)
            diag = float(np.linalg.norm(points.max(0) - points.min(0)))
            ext = ".las" if src.suffix in (".las", ".laz") else ".ply"
            for ratio in (float(r) for r in a.ratios.split(",")):
                kept, plain, t_plain = run(src, Path(tmp) / f"plain{ext}", ratio=ratio, cell_size=a.cell_size)
                keep = np.flatnonzero(cKDTree(kept).query(points)[0] == 0)
                d = cKDTree(kept).query(points)[0]
                med = float(np.median(d[d > 0]))
                cells, secs = [], []
                for mult in MULTIPLES:
                    D = mult * med
                    out, summary, t = run(src, Path(tmp) / f"gap{ext}", ratio=ratio, cell_size=a.cell_size, max_gap=D)
                    found = float(cKDTree(out).query(points)[0].max())
                    assert found <= D and summary.gap["max"] == found
                    greedy = len(greedy_fill(points, keep, gap=D)[0])
                    cells.append(f" {summary.gap['filled']:,} / {greedy:,} | {found / D:.3f} |")
                    secs.append(f"{t:.2f}")
                la = "/".join(f"{v:.1f}" for v in os.getloadavg())
                print(f"| {src.name} | {ratio:.0%} ({plain.kept:,}) | {plain.cells} | {100 * med / diag:.4f} |"
                      + "".join(cells) + f" {t_plain:.2f} / {' / '.join(secs)} | {la} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
