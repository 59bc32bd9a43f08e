"""A gap-closing pass after the default rule, at equal count and with a gap bound.

Run: ``.venv/bin/python benchmarks/gap.py [--ratios 0.5,0.2,0.1] [--cache FILE] [FILES...]``

The default rule (``eliminate``, run as ``cloudsieve compare`` runs it:
:func:`cloudsieve.evaluate.baselines.run_method` ``("km", ..., rule="eliminate")``)
followed by a **greedy farthest-point fill**: the original point farthest
from the kept set joins it, every distance to the kept set is updated, and
again (exact: a numba kernel on a uniform grid of cell size = the largest
distance before the fill, only the 27 cells around the added point change;
the largest distance comes from block maxima). Ties go to the lowest grid
order.

Table 1, equal count c, against the best of voxel, Poisson disk and farthest
point at c (:mod:`cloudsieve.evaluate.baselines`; each figure's best on its
own: least point max, least RMS, most D1 PSNR):

- ``plain``: the rule at c;
- ``fill f``: the rule at c - m, then m points filled, m = f x c;
- ``radius``: the least m (of a fixed-point search, at most 10 rule runs) for
  which the rule at c - m, then m points filled, leaves no original point
  farther than the best baseline's point max: the gap bound is met exactly
  and the count is c ("bound not met" when the search ends first).

Figures from :func:`cloudsieve.evaluate.evaluation.run_evaluation` (forward,
original -> kept, % of the bounding-box diagonal; D1 PSNR with the diagonal
as peak): point max x, RMS x (ratio to the best baseline, below 1 is better)
and D1 - best (dB, above 0 is better). Goal (issue #52 item 3): max x <= 1.00,
RMS x <= 0.97, D1 - best >= +0.30 dB. "fill s" is the fill kernel's seconds,
"rule s" the rule's (at c - m), on the benchmark machine under the load
printed.

Table 2, a gap bound D (``--max-gap``: the count becomes "at least"): the
rule at c, then the fill until no original point is farther than D, for D =
1.5, 2 and 3 times the median distance from a dropped original point to its
nearest kept point: the points added, as a count and as % of c.

Baseline figures go to ``--cache`` (JSON) and are reused on the next run.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from cloudsieve.evaluate.baselines import run_method
from cloudsieve.evaluate.evaluation import run_evaluation
from cloudsieve.io import read_cloud
from cloudsieve.params_spec import OPTION_CLASSES

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SCANS = ["bun_zipper.ply", "maxplanck.ply", "autzen_trim.laz", "Megaplot.laz", "append-bug.laz",
         "vegetation_1_3.las", "pumpAVisualReferenceImage.e57"]
BASELINES = ("voxel", "poisson", "fps")
FILLS = (0.005, 0.01, 0.02)
#: the gap bounds of table 2, times the median dropped -> kept distance
MULTIPLES = (1.5, 2, 3)
#: rule runs of the radius variant's search for m
RADIUS_RUNS = 10
#: block of the fill's running maximum (points, in grid order)
BLOCK = 256


@njit(cache=True)
def _block_max(d, b, B, bmax, barg):
    lo, hi = b * B, min((b + 1) * B, len(d))
    k = lo
    for j in range(lo + 1, hi):
        if d[j] > d[k]:
            k = j
    bmax[b] = d[k]
    barg[b] = k


@njit(cache=True)
def _greedy_fill(P, d, q, ukeys, cstart, dims, stop, max_add, B):
    """Add the farthest point until *max_add* are added or the largest distance is <= *stop*.

    P (n, 3), d (n,) distances to the kept set, q (n, 3) grid cells, all in grid order (sorted by cell key);
    ukeys/cstart the occupied cells and their first point. The cell size is >= max(d), so an added point can
    only bring closer the points of the 27 cells around it. Returns the added positions and the largest
    distance after each addition; updates d.
    """
    n = len(P)
    nb = (n + B - 1) // B
    bmax = np.empty(nb)
    barg = np.empty(nb, np.int64)
    for b in range(nb):
        _block_max(d, b, B, bmax, barg)
    added = np.empty(max_add, np.int64)
    after = np.empty(max_add)
    dirty = np.zeros(nb, np.bool_)
    dlist = np.empty(nb, np.int64)
    t = 0
    while t < max_add:
        i = barg[np.argmax(bmax)]
        if d[i] <= stop:
            break
        added[t] = i
        d[i] = 0.0
        nd = 1
        dlist[0] = i // B
        dirty[i // B] = True
        for dz in range(-1, 2):
            z = q[i, 2] + dz
            if z < 0 or z >= dims[2]:
                continue
            for dy in range(-1, 2):
                y = q[i, 1] + dy
                if y < 0 or y >= dims[1]:
                    continue
                for dx in range(-1, 2):
                    x = q[i, 0] + dx
                    if x < 0 or x >= dims[0]:
                        continue
                    key = x + dims[0] * (y + dims[1] * z)
                    c = np.searchsorted(ukeys, key)
                    if c >= len(ukeys) or ukeys[c] != key:
                        continue
                    for j in range(cstart[c], cstart[c + 1]):
                        e = np.sqrt((P[j, 0] - P[i, 0]) ** 2 + (P[j, 1] - P[i, 1]) ** 2
                                    + (P[j, 2] - P[i, 2]) ** 2)
                        if e < d[j]:
                            d[j] = e
                            b = j // B
                            if not dirty[b]:
                                dirty[b] = True
                                dlist[nd] = b
                                nd += 1
        for k in range(nd):
            _block_max(d, dlist[k], B, bmax, barg)
            dirty[dlist[k]] = False
        after[t] = bmax.max()
        t += 1
    return added[:t], after[:t]


def greedy_fill(P: np.ndarray, keep: np.ndarray, *, add: int | None = None, gap: float = -1.0):
    """The greedy farthest-point fill of the kept indices *keep* of *P*.

    Adds *add* points (default: as many as needed) or stops earlier once no point of *P* is farther than
    *gap* from the kept set. Returns (added original indices, largest distance after each addition,
    the distances before the fill).
    """
    d0 = cKDTree(P[keep]).query(P, workers=-1)[0]
    h = max(float(d0.max()), 1e-12)
    lo = P.min(0)
    q = np.floor((P - lo) / h).astype(np.int64)
    dims = q.max(0) + 1
    key = q[:, 0] + dims[0] * (q[:, 1] + dims[1] * q[:, 2])
    order = np.argsort(key, kind="stable")
    ks = key[order]
    ukeys, first = np.unique(ks, return_index=True)
    cstart = np.append(first, len(ks)).astype(np.int64)
    d = d0[order].copy()
    max_add = len(P) if add is None else int(add)
    pos, after = _greedy_fill(np.ascontiguousarray(P[order]), d, np.ascontiguousarray(q[order]), ukeys, cstart,
                              dims.astype(np.int64), float(gap), max_add, BLOCK)
    return order[pos], after, d0


def figures(P: np.ndarray, idx: np.ndarray) -> dict:
    """Point RMS / max (% of the diagonal) and D1 PSNR (dB), forward, from cloudsieve's evaluation."""
    options = OPTION_CLASSES["evaluate"](subset=True, surface=False, surface_budget=None, d2_sample=1000)
    rep = run_evaluation(P, P[idx], options)
    return {"count": int(len(idx)), "rms": rep["point"]["forward"]["rms_pct"],
            "max": rep["point"]["forward"]["max_pct"], "d1": rep["psnr"]["d1"]["forward"]}


def rule(P: np.ndarray, count: int) -> tuple[np.ndarray, float]:
    t = time.perf_counter()
    keep = run_method("km", P, count, rule="eliminate", seed=0)
    return keep, time.perf_counter() - t


def filled(P: np.ndarray, count: int, m: int) -> dict:
    """The rule at count - m, then m points filled."""
    keep, rs = rule(P, count - m)
    t = time.perf_counter()
    add, after, _ = greedy_fill(P, keep, add=m)
    fs = time.perf_counter() - t
    idx = np.union1d(keep, add)
    return {"idx": idx, "m": m, "rule_s": rs, "fill_s": fs, "after": after}


def radius(P: np.ndarray, count: int, D: float, diag: float) -> dict:
    """The least m found for which the rule at count - m plus m filled points leaves no gap above D (% diag).

    m starts at the points the fill needs after the rule at count and grows to what it needs after the rule at
    count - m, at most ``RADIUS_RUNS`` times; ``reached`` says whether the bound was met.
    """
    Dabs = D * diag / 100
    keep, _ = rule(P, count)
    m = len(greedy_fill(P, keep, gap=Dabs)[0])
    for _ in range(RADIUS_RUNS):
        out = filled(P, count, m)
        out["reached"] = m == 0 or bool(out["after"][-1] <= Dabs)
        if out["reached"]:
            return out
        keep, _ = rule(P, count - m)
        m = max(m + 1, len(greedy_fill(P, keep, gap=Dabs)[0]))
    return out


def ratios_to(best: dict, f: dict) -> dict:
    return {"max_x": f["max"] / best["max"], "rms_x": f["rms"] / best["rms"], "d1_d": f["d1"] - best["d1"]}


def run(files, ratios, cache_path) -> tuple[list, list]:
    store = json.loads(Path(cache_path).read_text()) if cache_path and Path(cache_path).is_file() else {}
    rows, gaps = [], []
    for name in files:
        path = Path(name) if Path(name).is_file() else DATA / name
        P = np.ascontiguousarray(read_cloud(str(path))[0], dtype=np.float64)
        diag = float(np.linalg.norm(P.max(0) - P.min(0)))
        for ratio in ratios:
            count = int(round(ratio * len(P)))
            key = f"{path.name}:{ratio}"
            if key not in store:
                store[key] = {b: figures(P, run_method(b, P, count, seed=0)) for b in BASELINES}
                if cache_path:
                    Path(cache_path).write_text(json.dumps(store, indent=1))
            base = store[key]
            best = {"max": min(b["max"] for b in base.values()), "rms": min(b["rms"] for b in base.values()),
                    "d1": max(b["d1"] for b in base.values())}
            la = "/".join(f"{v:.1f}" for v in os.getloadavg())
            row = {"scan": path.name, "ratio": ratio, "count": count, "best": best, "load": la, "variants": {}}
            keep, rs = rule(P, count)
            row["variants"]["plain"] = {"m": 0, "rule_s": rs, "fill_s": 0.0,
                                        **ratios_to(best, figures(P, keep))}
            for f in FILLS:
                out = filled(P, count, int(round(f * count)))
                row["variants"][f"fill {100 * f:g}%"] = {"m": out["m"], "rule_s": out["rule_s"],
                                                         "fill_s": out["fill_s"],
                                                         **ratios_to(best, figures(P, out["idx"]))}
            out = radius(P, count, best["max"], diag)
            row["variants"]["radius"] = {"m": out["m"], "reached": out["reached"], "rule_s": out["rule_s"],
                                         "fill_s": out["fill_s"],
                                         **ratios_to(best, figures(P, out["idx"]))}
            rows.append(row)
            # the gap bound: the rule at the count, then the fill to D
            _, _, d0 = greedy_fill(P, keep, add=0)
            med = float(np.median(d0[d0 > 0]))
            g = {"scan": path.name, "ratio": ratio, "count": count, "max": 100 * float(d0.max()) / diag,
                 "median": 100 * med / diag, "load": la, "bounds": {}}
            for mult in MULTIPLES:
                t = time.perf_counter()
                add, _, _ = greedy_fill(P, keep, gap=mult * med)
                g["bounds"][mult] = {"D": 100 * mult * med / diag, "added": int(len(add)),
                                     "seconds": time.perf_counter() - t}
            gaps.append(g)
            print(f"done {path.name} {ratio}", file=sys.stderr, flush=True)
    return rows, gaps


def meets(v: dict) -> bool:
    return v["max_x"] <= 1.0 and v["rms_x"] <= 0.97 and v["d1_d"] >= 0.3


def markdown(rows: list) -> str:
    lines = ["| scan | kept | best max % / RMS % / D1 dB | variant | m | max x | RMS x | D1 - best (dB) | "
             "all three goals | rule s | fill s | load |",
             "|---|---|---|---|---:|---:|---:|---:|---|---:|---:|---|"]
    for r in rows:
        b = r["best"]
        for name, v in r["variants"].items():
            lines.append(f"| {r['scan']} | {r['ratio']:.0%} ({r['count']:,}) | {b['max']:.3f} / {b['rms']:.4f} / "
                         f"{b['d1']:.2f} | {name} | {v['m']:,}{'' if v.get('reached', True) else ' (bound not met)'} | "
                         f"{v['max_x']:.3f} | {v['rms_x']:.3f} | "
                         f"{v['d1_d']:+.2f} | {'yes' if meets(v) else 'no'} | {v['rule_s']:.2f} | "
                         f"{v['fill_s']:.3f} | {r['load']} |")
    names = list(rows[0]["variants"]) if rows else []
    lines += ["", "| variant | rows with max x <= 1.00 | RMS x <= 0.97 | D1 - best >= +0.30 | all three | of |",
              "|---|---:|---:|---:|---:|---:|"]
    for name in names:
        vs = [r["variants"][name] for r in rows]
        lines.append(f"| {name} | {sum(v['max_x'] <= 1.0 for v in vs)} | {sum(v['rms_x'] <= 0.97 for v in vs)} | "
                     f"{sum(v['d1_d'] >= 0.3 for v in vs)} | {sum(meets(v) for v in vs)} | {len(vs)} |")
    return "\n".join(lines)


def gap_markdown(gaps: list) -> str:
    head = "".join(f" D = {k:g} x median % | points added | % of count |" for k in MULTIPLES)
    lines = ["| scan | kept | rule's max % | median dropped -> kept % |" + head + " fill s | load |",
             "|---|---|---:|---:|" + "---:|---:|---:|" * len(MULTIPLES) + "---|---|"]
    for g in gaps:
        cells = "".join(f" {b['D']:.4f} | {b['added']:,} | {100 * b['added'] / g['count']:.2f}% |"
                        for b in (g["bounds"][k] for k in MULTIPLES))
        secs = " / ".join(f"{g['bounds'][k]['seconds']:.2f}" for k in MULTIPLES)
        lines.append(f"| {g['scan']} | {g['ratio']:.0%} ({g['count']:,}) | {g['max']:.3f} | {g['median']:.4f} |"
                     + cells + f" {secs} | {g['load']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", default=SCANS)
    ap.add_argument("--ratios", default="0.5,0.2,0.1")
    ap.add_argument("--cache", default=None, help="JSON file of the baselines' figures (read and written)")
    ap.add_argument("--json", default=None, help="write the rows there too")
    a = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    warnings.filterwarnings("ignore")
    warm = np.random.default_rng(0).random((64, 3))
    greedy_fill(warm, np.arange(8), add=4)  # compile the kernel before any timing
    rows, gaps = run(a.files, [float(x) for x in a.ratios.split(",")], a.cache)
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "gaps": gaps}, indent=1))
    print("## The rule, then a greedy farthest-point fill, at equal count\n")
    print(markdown(rows))
    print("\n## Points the fill adds for a gap bound D (count: at least c)\n")
    print(gap_markdown(gaps))
    return 0


if __name__ == "__main__":
    sys.exit(main())
