"""Nested outputs (``--ratio 0.5,0.2,0.1``): how they differ from separate runs, and what they cost.

    .venv/bin/python benchmarks/nested.py                           # autzen_trim and bun_zipper, 3 cost runs
    .venv/bin/python benchmarks/nested.py --cost scan2000000.laz --repeat 2
    .venv/bin/python benchmarks/nested.py --gone                    # the cascade with the removed points as context

Quality: for each scan, the nested outputs and a separate run at each ratio;
per ratio the symmetric difference |A Δ B| / (|A| + |B|) of their points, the
share of the separate run inside the separate run at the ratio before, and
the forward point RMS / max (% of the diagonal) of both. Cost: ``cloudsieve
simplify`` in a fresh process at 0.5, at 0.1 and at 0.5,0.2,0.1, alternating;
the median wall and CPU time of each (the process and its children) and the
load average before the runs.

``--gone``: the cascade on arrays, one elimination a level over k-d cells
(``eliminate_cell``, not the engine's cells), each level on the points the
level before kept, without and with the original's other points as gone
context (halo points decided and removed: the coverage term represents them
by their nearest kept point), against a separate elimination at each ratio;
point RMS / max (% of the diagonal), every ratio's r_max solved on the whole
cloud.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

import cloudsieve

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
RATIOS = (0.5, 0.2, 0.1)


def _points(path: str) -> set:
    if path.endswith(".ply"):
        return {bytes(r) for r in np.ascontiguousarray(cloudsieve.read_cloud(path)[0]).view(np.uint8).reshape(-1, 24)}
    cloud = laspy.read(path)
    return {bytes(r) for r in np.ascontiguousarray(cloud.points.array).view(np.uint8).reshape(len(cloud), -1)}


def quality(src: Path, work: Path) -> None:
    ext = ".ply" if src.suffix == ".ply" else ".laz"
    summary = cloudsieve.simplify(src, work / f"nested{ext}", ratio=RATIOS, overwrite=True)
    separate = {}
    for r in RATIOS:
        separate[r] = str(work / f"separate-{r}{ext}")
        cloudsieve.simplify(src, separate[r], ratio=r, overwrite=True)
    print(f"\n{src.name}\n\n| ratio | sym. diff. | separate inside the one before | RMS / max nested | RMS / max separate |")
    print("| --- | --- | --- | --- | --- |")
    for i, (r, out) in enumerate(zip(RATIOS, summary.outputs)):
        a, b = _points(separate[r]), _points(out["destination"])
        inside = f"{len(a & _points(separate[RATIOS[i - 1]])) / len(a):.4f}" if i else "-"
        errors = []
        for path in (out["destination"], separate[r]):
            forward = cloudsieve.evaluate(src, path, surface=False)["point"]["forward"]
            errors.append(f"{forward['rms_pct']:.4f} / {forward['max_pct']:.4f}")
        print(f"| {r:g} | {len(a ^ b) / (len(a) + len(b)):.3f} | {inside} | {errors[0]} | {errors[1]} |")


def cost(src: Path, work: Path, repeat: int) -> None:
    cases = {"0.5": "0.5", "0.1": "0.1", "0.5,0.2,0.1": "0.5,0.2,0.1"}
    wall = {k: [] for k in cases}
    cpu = {k: [] for k in cases}
    load = os.getloadavg()[0]
    for _ in range(repeat):
        for label, ratio in cases.items():
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = os.times().elapsed
            subprocess.run([sys.executable, "-m", "cloudsieve", "simplify", str(src), str(work / "cost.laz"),
                            "--ratio", ratio, "--overwrite", "--no-progress"], check=True, capture_output=True)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            wall[label].append(os.times().elapsed - t0)
            cpu[label].append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    print(f"\n{src.name}, load {load:.1f} before the runs\n\n| ratio | wall (s) | CPU (s) |\n| --- | --- | --- |")
    for label in cases:
        print(f"| {label} | {statistics.median(wall[label]):.2f} | {statistics.median(cpu[label]):.2f} |")
    three = statistics.median(wall["0.5,0.2,0.1"])
    print(f"\nthree / 0.5 alone {three / statistics.median(wall['0.5']):.2f}x, three / 0.1 alone "
          f"{three / statistics.median(wall['0.1']):.2f}x (wall)")


def gone_context(src: Path) -> None:
    from scipy.spatial import cKDTree

    from cloudsieve.core.elimination import area_radius
    from cloudsieve.core.eliminate_cells import eliminate_cell

    xyz = np.asarray(cloudsieve.read_cloud(str(src))[0], dtype=np.float64)
    n, diag = len(xyz), float(np.linalg.norm(xyz.max(axis=0) - xyz.min(axis=0)))

    def errors(mask):
        d, _ = cKDTree(xyz[mask]).query(xyz)
        return f"{100 * np.sqrt(np.mean(d * d)) / diag:.4f} / {100 * d.max() / diag:.4f}"

    def keep(candidates, q, r_max, gone):
        rows = np.flatnonzero(candidates)
        halo = {}
        if gone and not candidates.all():
            other = xyz[~candidates]
            halo = {"halo": other, "decided": np.ones(len(other), dtype=bool),
                    "halo_keep": np.zeros(len(other), dtype=bool)}
        out = np.zeros(n, dtype=bool)
        out[rows[eliminate_cell(xyz[rows], q, r_max, cell_points=16_384, **halo)]] = True
        return out

    print(f"\n{src.name}, RMS / max\n\n| ratio | separate | nested | nested, gone context |\n| --- | --- | --- | --- |")
    plain = gone = np.ones(n, dtype=bool)
    for r in RATIOS:
        q = round(r * n)
        r_max = area_radius(xyz, xyz, q)
        plain, gone = keep(plain, q, r_max, False), keep(gone, q, r_max, True)
        alone = keep(np.ones(n, dtype=bool), q, r_max, False)
        print(f"| {r:g} | {errors(alone)} | {errors(plain)} | {errors(gone)} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", default="autzen_trim.laz,bun_zipper.ply", help="shared scans for the quality table")
    ap.add_argument("--cost", default=str(DATA / "autzen_trim.laz"), help="the file the cost runs simplify")
    ap.add_argument("--repeat", type=int, default=3, help="cost runs of each case (default 3)")
    ap.add_argument("--gone", action="store_true", help="only the cascade with the removed points as context")
    args = ap.parse_args(argv)
    if args.gone:
        for name in filter(None, args.scans.split(",")):
            gone_context(DATA / name)
        return 0
    with tempfile.TemporaryDirectory(prefix="cloudsieve-nested-") as tmp:
        for name in filter(None, args.scans.split(",")):
            quality(DATA / name, Path(tmp))
        cost(Path(args.cost), Path(tmp), args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
