"""In-memory ``eliminate`` speed: points/s at 1 M points on 1 and 2 threads, beside Open3D's voxel grid.

    .venv/bin/python benchmarks/eliminate_speed.py                   # 1 M points, 50%, 3 rounds
    .venv/bin/python benchmarks/eliminate_speed.py --points 1000000 --ratio 0.1 --rounds 5

The cloud is benchmarks/core.py's generated surface (a height field with
small noise). Each round runs, each in a fresh Python process so that no run
inherits another's caches or heap, one after the other: ``eliminate(P,
ratio=R, threads=T)`` for T = 1 and 2 (5 calls after one on 50,000 points,
which loads the kernels from numba's cache), and Open3D's
``voxel_down_sample`` on the same points at the voxel size that keeps about
as many (found by bisection before the timed calls). Prints a Markdown table:
fastest and median of each, points/s of the fastest, the CPU seconds of the
eliminate calls (``resource.getrusage``), the md5 of the kept indices (the
same for every thread count) and the load average before each process.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import hashlib, json, resource, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from core import surface
n, ratio, what, calls = int(sys.argv[2]), float(sys.argv[3]), sys.argv[4], int(sys.argv[5])
pts = surface(n)
times, cpu, kept = [], 0.0, ""
if what == "open3d":
    import open3d as o3d
    from engine import voxel_same_count
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts - pts.min(axis=0)))
    voxel = voxel_same_count(pcd, round(ratio * n))  # the voxel that keeps about as many points (untimed)
    for _ in range(calls):
        t = time.perf_counter()
        k = len(pcd.voxel_down_sample(voxel).points)
        times.append(time.perf_counter() - t)
    kept = f"{k:,} points"
else:
    from cloudsieve.core.eliminate import eliminate
    threads = int(what)
    eliminate(pts[:50_000], ratio=ratio, threads=threads)
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    for _ in range(calls):
        t = time.perf_counter()
        kept = eliminate(pts, ratio=ratio, threads=threads)
        times.append(time.perf_counter() - t)
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime) / calls
    kept = hashlib.md5(kept.tobytes()).hexdigest()[:12]
print(json.dumps({"times": times, "cpu": cpu, "kept": kept}))
"""


def run(n: int, ratio: float, what: str, calls: int) -> dict:
    load = os.getloadavg()[0]
    out = subprocess.run([sys.executable, "-c", CHILD, str(HERE), str(n), str(ratio), what, str(calls)],
                         check=True, capture_output=True, text=True).stdout
    res = json.loads(out.strip().splitlines()[-1])
    res["load"] = load
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--ratio", type=float, default=0.5)
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the three processes (default 3)")
    ap.add_argument("--calls", type=int, default=5, help="timed calls per process (default 5)")
    args = ap.parse_args(argv)
    n = args.points
    print(f"# in-memory eliminate, {n:,} points, ratio {args.ratio}, {os.cpu_count()} cores\n")
    print("| round | run | fastest / median (s) | points/s (fastest) | CPU s a call | kept | load |")
    print("|---:|---|---|---:|---:|---|---:|")
    for r in range(1, args.rounds + 1):
        for what, name in (("1", "`eliminate`, 1 thread"), ("2", "`eliminate`, 2 threads"),
                           ("open3d", "Open3D `voxel_down_sample` (same count)")):
            res = run(n, args.ratio, what, args.calls)
            t = sorted(res["times"])
            cpu = f"{res['cpu']:.2f}" if what != "open3d" else ""
            print(f"| {r} | {name} | {t[0]:.3f} / {t[len(t) // 2]:.3f} | {n / t[0]:,.0f} | {cpu} | {res['kept']} | "
                  f"{res['load']:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
