"""Quality of the ``eliminate`` rule against voxel, Poisson disk and farthest point at equal count.

Run: ``.venv/bin/python benchmarks/eliminate_quality.py [--ratios 0.5,0.2,0.1] [--cache FILE] [FILES...]``

For every scan of ../shared/data with at least 10,000 points (default:
bun_zipper.ply, maxplanck.ply, autzen_trim.laz, Megaplot.laz, append-bug.laz,
vegetation_1_3.las, pumpAVisualReferenceImage.e57) and every ratio, the
baselines of :mod:`cloudsieve.evaluate.baselines` (voxel_subset,
poisson_subset, fps_subset; voxel and Poisson land within 0.5% of the count,
farthest point on it) and the rule (:func:`cloudsieve.core.eliminate.eliminate`)
in each variant:

- ``off``: the default (coverage and squared-error terms, no information term;
  over cells of 16,384 points above that many, :mod:`cloudsieve.core.eliminate_cells`);
- ``one cell``: the same, one elimination over the whole cloud (with ``--one-cell``).

(The ``entropy`` and ``geometric`` variants of docs/benchmarks.md ran the
information terms, removed since.)

Figures, from :func:`cloudsieve.evaluate.evaluate` (``subset=True``; its ``run_evaluation``, which keeps the
original's tile meshes between calls): point
RMS and max (original -> simplified, % of the bounding-box diagonal) and the
Metro mean (surface level, % of the diagonal: the larger of its two
directions' means, both printed in a second table).

Equal count, each baseline at its own count: the rule is run at the count of
every baseline, and a point ratio is the largest over the three baselines of
rule / baseline; the Metro ratio is rule / the baseline with the lowest Metro
mean, the rule at that baseline's count. Goals: point RMS <= 1.00, point max
<= 1.25, Metro mean <= 1.00 (<= 0.90 on bun_zipper and maxplanck).

Prints a Markdown table (absolute figures of the best baseline, then the
ratios per variant, and the rule's seconds at the first count). Baseline
results go to ``--cache`` (JSON) and are reused on the next run.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from cloudsieve.core.eliminate import eliminate
from cloudsieve.evaluate.evaluation import run_evaluation
from cloudsieve.evaluate.baselines import fps_subset, poisson_subset, voxel_subset
from cloudsieve.io import read_cloud
from cloudsieve.params_spec import OPTION_CLASSES

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SCANS = ["bun_zipper.ply", "maxplanck.ply", "autzen_trim.laz", "Megaplot.laz", "append-bug.laz",
         "vegetation_1_3.las", "pumpAVisualReferenceImage.e57"]
BASELINES = {"voxel": voxel_subset, "poisson": poisson_subset, "fps": fps_subset}


def figures(P: np.ndarray, idx: np.ndarray, cache: dict, surface: bool = True) -> dict:
    options = OPTION_CLASSES["evaluate"](subset=True, surface=surface, tiles=4, surface_budget=None)  # 4 tiles, no budget
    rep = run_evaluation(P, P[idx], options, surface_cache=cache)
    out = {"count": int(len(idx)), "rms": rep["point"]["forward"]["rms_pct"],
           "max": rep["point"]["forward"]["max_pct"]}
    if surface:
        out["metro"] = rep["surface"]["mean_pct"]  # the larger of the two directions' means
        out["metro_fwd"] = rep["surface"]["forward"]["mean_pct"]  # samples on the original's mesh
        out["metro_bwd"] = rep["surface"]["backward"]["mean_pct"]  # samples on the simplified cloud's mesh
    return out


def variants(P: np.ndarray, one_cell: bool = False) -> dict:
    out = {"off": {}}
    if one_cell:
        out["one cell"] = {"cell_points": None}
    return out


def run(files, ratios, cache_path, one_cell: bool = False) -> list[dict]:
    store = json.loads(Path(cache_path).read_text()) if cache_path and Path(cache_path).is_file() else {}
    rows = []
    for name in files:
        path = Path(name) if Path(name).is_file() else DATA / name
        P = read_cloud(str(path))[0]
        surf: dict = {}
        vs = variants(P, one_cell)
        for ratio in ratios:
            count = int(round(ratio * len(P)))
            key = f"{path.name}:{ratio}"
            if key not in store or any("metro_fwd" not in f for f in store[key].values()):
                store[key] = {b: figures(P, fn(P, count), surf) for b, fn in BASELINES.items()}
                if cache_path:
                    Path(cache_path).write_text(json.dumps(store, indent=1))
            base = store[key]
            best_metro = min(base, key=lambda b: base[b]["metro"])
            row = {"scan": path.name, "points": len(P), "ratio": ratio, "count": count, "best_metro": best_metro,
                   "best_dirs": {d: base[best_metro][d] for d in ("metro_fwd", "metro_bwd")},
                   "best": {m: min(base[b][m] for b in base) for m in ("rms", "max", "metro")}, "variants": {}}
            for v, opts in vs.items():
                rms = mx = 0.0
                metro = fwd = bwd = None
                seconds = None
                for b, fig in base.items():
                    t = time.perf_counter()
                    keep = eliminate(P, fig["count"], **opts)
                    seconds = seconds if seconds is not None else time.perf_counter() - t
                    mine = figures(P, keep, surf, surface=(b == best_metro))
                    rms = max(rms, mine["rms"] / fig["rms"])
                    mx = max(mx, mine["max"] / fig["max"])
                    if b == best_metro:
                        metro = mine["metro"] / fig["metro"]
                        fwd = mine["metro_fwd"] / fig["metro_fwd"]
                        bwd = mine["metro_bwd"] / fig["metro_bwd"]
                row["variants"][v] = {"rms": rms, "max": mx, "metro": metro, "metro_fwd": fwd, "metro_bwd": bwd,
                                      "seconds": seconds}
            rows.append(row)
            print(f"done {path.name} {ratio}", file=sys.stderr, flush=True)
    return rows


def markdown(rows: list[dict]) -> str:
    vs = list(rows[0]["variants"]) if rows else []
    head = "| scan | kept | best RMS % | best max % | best Metro % | " + " | ".join(
        f"{v}: RMS x | {v}: max x | {v}: Metro x | {v}: s" for v in vs) + " |"
    lines = [head, "|" + "---|" * (5 + 4 * len(vs))]
    for r in rows:
        cells = [f"{r['scan']}", f"{r['ratio']:.0%}", f"{r['best']['rms']:.4f}", f"{r['best']['max']:.4f}",
                 f"{r['best']['metro']:.5f}"]
        for v in vs:
            x = r["variants"][v]
            cells += [f"{x['rms']:.3f}", f"{x['max']:.3f}", f"{x['metro']:.3f}", f"{x['seconds']:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def directions(rows: list[dict]) -> str:
    """Metro's two directions: the best-Metro baseline's means and the rule's ratio to each."""
    vs = list(rows[0]["variants"]) if rows else []
    head = ("| scan | kept | best Metro baseline | its forward % | its backward % | "
            + " | ".join(f"{v}: forward x | {v}: backward x" for v in vs) + " |")
    lines = [head, "|" + "---|" * (5 + 2 * len(vs))]
    for r in rows:
        cells = [r["scan"], f"{r['ratio']:.0%}", r["best_metro"], f"{r['best_dirs']['metro_fwd']:.5f}",
                 f"{r['best_dirs']['metro_bwd']:.5f}"]
        for v in vs:
            x = r["variants"][v]
            cells += [f"{x['metro_fwd']:.3f}", f"{x['metro_bwd']:.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", default=SCANS)
    ap.add_argument("--ratios", default="0.5,0.2,0.1")
    ap.add_argument("--cache", default=None, help="JSON file of the baselines' figures (read and written)")
    ap.add_argument("--one-cell", action="store_true", help="also the default as one elimination (no cells)")
    ap.add_argument("--json", default=None, help="write the rows there too")
    a = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    warnings.filterwarnings("ignore")
    rows = run(a.files, [float(x) for x in a.ratios.split(",")], a.cache, a.one_cell)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    print("## eliminate / best of voxel, Poisson, farthest point at equal count\n")
    print("Point ratios: the largest over the three baselines, the rule at each one's count. Metro ratio: "
          "against the baseline of lowest Metro mean, at its count. % of the bounding-box diagonal.\n")
    print(markdown(rows))
    print("\n## Metro's two directions (the Metro mean is the larger)\n")
    print("Forward: samples on the original's mesh, distance to the simplified cloud's mesh (what the simplified "
          "mesh misses). Backward: samples on the simplified cloud's mesh, distance to the original's. Ratios: "
          "the rule / the baseline of lowest Metro mean, at its count.\n")
    print(directions(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
