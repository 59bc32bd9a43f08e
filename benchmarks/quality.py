"""Point-level quality of the rules at equal count.

Run: ``.venv/bin/python benchmarks/quality.py [--ratio 0.5] [--method km] [FILES...]``
or   ``.venv/bin/python benchmarks/quality.py --psnr [--ratios 0.5,0.2,0.1] [FILES...]``

``--psnr``: MPEG pc_error's D1 and D2 PSNR, forward (A = original -> B =
simplified: how well the kept points represent the original,
:mod:`cloudsieve.evaluate.planes`), and the one-sided point RMS and max
(original -> kept, % of the bounding-box diagonal; the max is the gap bound:
no original point is farther from the kept set) of ``eliminate`` and of the
voxel, Poisson-disk and farthest-point baselines at the same count, on each
scan and kept share: one ``cloudsieve compare SRC --ratio R --methods
km,voxel,poisson,fps --no-surface`` each (its table has the same figures,
one row per method), gathered into one table, one row per method (dB, peak
= the original's bounding-box diagonal; D2 on normals by PCA of 12
neighbours, every point of these scans). ``eliminate``'s row also gives its
ratios to the best baseline of its scan and share, each figure's best on
its own: point max x (least max), RMS x (least RMS), D1 - best (dB, most
D1), and the gap bound: the points ``--max-gap D`` adds back to the rule's
count for D = the best baseline's point max (``cloudsieve.simplify(...,
max_gap=D)``, in memory; the count becomes at least c). Default scans: every real scan of ../shared/data of at least 10,000
points.

For each real scan (default: bun_zipper.ply, maxplanck.ply, autzen_trim.laz in
../shared/data), keep ``ratio`` of the points with:

- one-pass dH: the paper's threshold rule, S chosen so that the count is met;
- one-pass m*dH: the ``target`` rule;
- iterative: the ``iterative`` rule with the target (rounds of independent
  removals, rescoring between rounds);
- coverage: cloudsieve's ``coverage`` rule with the target;
- the same two with ``context=`` an empty array: r_k measured among all the
  points (every cluster), not the point's cluster alone;
- random: a uniform random subset (seed 0);
- voxel-nearest: a voxel grid whose size is bisected to reach the count, keeping
  the original point nearest each occupied voxel's centroid.

and report the one-sided distance from every original point to the simplified
cloud (RMS, mean and max, as % of the bounding-box diagonal). Entropy rules
use the same clusters (KM by default, ~400 points each, seed 0).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from cloudsieve.core.entropy import score_points
from cloudsieve.core import prune, refine_labels, threshold_for_count

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def read_points(path: Path) -> np.ndarray:
    from cloudsieve.io import read_cloud

    return read_cloud(str(path))[0]


def errors(P: np.ndarray, Q: np.ndarray):
    d = cKDTree(Q).query(P, workers=-1)[0]
    diag = float(np.linalg.norm(P.max(0) - P.min(0)))
    return 100 * np.sqrt((d**2).mean()) / diag, 100 * d.mean() / diag, 100 * d.max() / diag


def voxel_nearest(P: np.ndarray, target: int) -> np.ndarray:
    lo = P.min(0)
    diag = float(np.linalg.norm(P.max(0) - lo))

    def run(h):
        key = np.floor((P - lo) / h).astype(np.int64)
        _, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.ravel()
        cnt = np.bincount(inv)
        cen = np.stack([np.bincount(inv, P[:, j]) for j in range(3)], 1) / cnt[:, None]
        d = ((P - cen[inv]) ** 2).sum(1)
        o = np.lexsort((d, inv))
        return np.sort(o[np.r_[True, inv[o][1:] != inv[o][:-1]]])

    a, b = 1e-7 * diag, diag
    for _ in range(60):
        h = np.sqrt(a * b)
        if len(run(h)) > target:
            a = h
        else:
            b = h
    return run(a)


def table(files, ratio: float, method: str) -> str:
    rows = ["| cloud | points | rule | kept | RMS % diag | mean % diag | max % diag | seconds |",
            "|---|---:|---|---:|---:|---:|---:|---:|"]
    for name in files:
        path = Path(name) if Path(name).is_file() else DATA / name
        P = read_points(path)
        n = len(P)
        tgt = int(round(ratio * n))
        t = time.perf_counter()
        labels = refine_labels(P, method, 400, 0)
        t_ref = time.perf_counter() - t
        runs = {}

        def timed(key, fn):
            t0 = time.perf_counter()
            runs[key] = (fn(), time.perf_counter() - t0)

        def one_pass_dh():
            dh = score_points(P, labels).delta_h
            S = threshold_for_count(dh, n - tgt)
            return np.flatnonzero(prune(P, labels, rule="threshold", threshold=S))

        timed("one-pass dH (paper, S fitted)", one_pass_dh)
        timed("one-pass m*dH (target)", lambda: np.flatnonzero(prune(P, labels, rule="target", ratio=ratio)))
        timed("iterative", lambda: np.flatnonzero(prune(P, labels, rule="iterative", ratio=ratio)))
        timed("coverage", lambda: np.flatnonzero(prune(P, labels, rule="coverage", ratio=ratio)))
        whole = np.empty((0, 3))  # context mode with no extra points: density neighbours from every cluster
        timed("iterative, whole-cloud neighbours",
              lambda: np.flatnonzero(prune(P, labels, rule="iterative", ratio=ratio, context=whole)))
        timed("coverage, whole-cloud neighbours",
              lambda: np.flatnonzero(prune(P, labels, rule="coverage", ratio=ratio, context=whole)))
        timed("random", lambda: np.sort(np.random.default_rng(0).choice(n, tgt, replace=False)))
        timed("voxel-nearest", lambda: voxel_nearest(P, tgt))
        for key, (kept, sec) in runs.items():
            rms, mean, mx = errors(P, P[kept])
            extra = f" (+{t_ref:.1f} refine)" if key.startswith(("one", "iter", "cov")) else ""
            rows.append(f"| {path.name} | {n:,} | {key} | {len(kept):,} | {rms:.3f} | {mean:.3f} | {mx:.3f} | "
                        f"{sec:.1f}{extra} |")
        print(f"done {path.name}", file=sys.stderr, flush=True)
    return "\n".join(rows)


PSNR_FILES = ["bun_zipper.ply", "maxplanck.ply", "autzen_trim.laz", "Megaplot.laz", "append-bug.laz",
              "vegetation_1_3.las", "pumpAVisualReferenceImage.e57"]
PSNR_METHODS = ("eliminate", "voxel", "poisson", "fps")


def best_baseline(rows: dict) -> dict:
    """The best of the baselines' figures in *rows* (method -> compare row): least point max, least RMS, most D1."""
    base = [r for m, r in rows.items() if m != "eliminate" and "error" not in r]
    if not base:
        return {}
    return {"point_max_pct": min(r["point_max_pct"] for r in base),
            "point_rms_pct": min(r["point_rms_pct"] for r in base),
            "d1_psnr": max(r["d1_psnr"] for r in base)}


def gap_bound_added(path: Path, ratio: float, gap: float) -> int:
    """The points ``--max-gap gap`` adds back to ``eliminate`` at *ratio* on *path* (the summary's count)."""
    import tempfile

    import cloudsieve

    ext = ".las" if path.suffix in (".las", ".laz") else ".ply"
    with tempfile.TemporaryDirectory() as tmp:
        return int(cloudsieve.simplify(path, Path(tmp) / f"out{ext}", ratio=ratio, max_gap=gap).gap["filled"])


def psnr_table(files, ratios) -> str:
    """One row per scan, kept share and method: forward D1 / D2 PSNR, point RMS and max, eliminate's ratios."""
    import os

    from cloudsieve.evaluate import compare

    rows = ["| scan | points | kept | method | kept points | D1 PSNR | D2 PSNR | point RMS % | point max % | "
            "max x best | RMS x best | D1 - best (dB) | gap bound: added at best max | load average |",
            "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name in files:
        path = Path(name) if Path(name).is_file() else DATA / name
        pts = read_points(path)
        diag = float(np.linalg.norm(pts.max(0) - pts.min(0)))
        for ratio in ratios:
            res = compare(str(path), methods=("km", "voxel", "poisson", "fps"), ratio=ratio, surface=False)
            by = {r["method"]: r for r in res["rows"]}
            best = best_baseline(by)
            la = "/".join(f"{v:.1f}" for v in os.getloadavg())
            for m in PSNR_METHODS:
                r = by.get(m)
                head = f"| {path.name} | {res['points']:,} | {100 * ratio:.0f}% ({res['count']:,}) | {m} |"
                if r is None or "error" in r:
                    rows.append(head + f" - | {r['error'] if r else 'not run'} | | | | | | | | {la} |")
                    continue
                vs = " | | | |"
                if m == "eliminate" and best:
                    added = gap_bound_added(path, ratio, best["point_max_pct"] * diag / 100)
                    vs = (f" {r['point_max_pct'] / best['point_max_pct']:.3f} |"
                          f" {r['point_rms_pct'] / best['point_rms_pct']:.3f} |"
                          f" {r['d1_psnr'] - best['d1_psnr']:+.2f} | {added:,} ({100 * added / r['kept']:.2f}%) |")
                rows.append(head + f" {r['kept']:,} | {r['d1_psnr']:.2f} | {r['d2_psnr']:.2f} | "
                            f"{r['point_rms_pct']:.4f} | {r['point_max_pct']:.3f} |" + vs + f" {la} |")
            print("\n".join(rows[-len(PSNR_METHODS):]), file=sys.stderr, flush=True)
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*")
    ap.add_argument("--ratio", type=float, default=0.5)
    ap.add_argument("--method", choices=("km", "fcm"), default="km")
    ap.add_argument("--psnr", action="store_true", help="D1/D2 PSNR of eliminate and the baselines at equal count")
    ap.add_argument("--ratios", default="0.5,0.2,0.1", help="--psnr's kept shares (default 0.5,0.2,0.1)")
    a = ap.parse_args(argv)
    if a.psnr:
        ratios = [float(v) for v in a.ratios.split(",")]
        print("## Forward D1 / D2 PSNR (dB), point RMS and max (% of the diagonal), original -> simplified, "
              "at equal count\n")
        print(psnr_table(a.files or PSNR_FILES, ratios))
        return 0
    print(f"## Point-level error at {a.ratio:.0%} kept ({a.method.upper()} clusters of ~400 points)\n")
    print("One-sided distance from every original point to the simplified cloud, as % of the "
          "bounding-box diagonal.\n")
    print(table(a.files or ["bun_zipper.ply", "maxplanck.ply", "autzen_trim.laz"], a.ratio, a.method))
    return 0


if __name__ == "__main__":
    sys.exit(main())
