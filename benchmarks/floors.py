"""Benchmark of the out-of-core stages against their floors, in the same run: a tiled delivery to tiles + VPC.

    .venv/bin/python benchmarks/floors.py                      # 20 M points in 5 LAZ tiles
    .venv/bin/python benchmarks/floors.py --size 2e6 --files 2 # a quick look

``--size`` points in ``--files`` make_scan LAZ tiles, simplified as one cloud to tiles + index.vpc
(``--ratio 0.5 --workers W``, a CLI run with ``--json``), then, on the same files and in the same run:

- **decode floor**: laspy + lazrs (one thread) decoding every input file in chunks of 1 M points, one task per
  file on a pool of W processes (laspy imported before the clock): the sum of the tasks' own times / W;
- **encode floor**: laspy + lazrs (one thread) encoding the kept points (the output tiles, read before the
  clock) to LAZ in memory, one task per tile on the same pool: the sum of the tasks' encode times / W;
- **in memory**: ``cloudsieve.simplify_points`` (the same cell scheme on arrays, on every core) of the input's
  coordinates, read before the clock: the engine's partition + cells against it.

A floor is the work of the library that does the stage's I/O, split evenly over the workers; the ratio is the
stage's wall time over it (for export also its workers' CPU over the encode tasks' CPU summed). The table has the run's points/s, CPU per point (driver + workers), the partition's
share of the run, and the load average before and after. Never run two benchmarks at once.
"""

from __future__ import annotations

import argparse
import io
import multiprocessing as mp
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
sys.path.insert(0, str(ROOT / "benchmarks"))

from scale import cli, load, make  # noqa: E402

CHUNK = 1_000_000


def _warm(_: int) -> int:
    import laspy  # noqa: F401  (imported before the clock)

    return 0


def decode_seconds(path: str) -> tuple[float, int]:
    """(seconds, points) of laspy + lazrs decoding *path* in chunks, in this process, one thread."""
    import laspy

    t0, n = time.perf_counter(), 0
    with laspy.open(path, laz_backend=laspy.LazBackend.Lazrs) as reader:
        for chunk in reader.chunk_iterator(CHUNK):
            n += len(chunk)
    return time.perf_counter() - t0, n


def encode_seconds(path: str) -> tuple[float, int, float]:
    """(seconds, points, CPU seconds) of laspy + lazrs encoding the points of *path* (read first, not timed) to LAZ
    in memory."""
    import laspy

    las = laspy.read(path)
    out = io.BytesIO()
    t0, c0 = time.perf_counter(), time.process_time()
    with laspy.open(out, mode="w", header=las.header, do_compress=True, laz_backend=laspy.LazBackend.Lazrs,
                    closefd=False) as writer:
        for start in range(0, len(las.points), CHUNK):
            writer.write_points(las.points[start : start + CHUNK])
    return time.perf_counter() - t0, len(las.points), time.process_time() - c0


IN_MEMORY = r"""
import sys, time, json
import numpy as np, laspy
import cloudsieve
xyz = np.concatenate([np.stack([f.x, f.y, f.z], axis=1) for f in map(laspy.read, sys.argv[1:])])
t0 = time.perf_counter(); c0 = time.process_time()
keep = cloudsieve.simplify_points(xyz, rule="eliminate", ratio=0.5)
print(json.dumps({"seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0, "kept": int(len(keep))}))
"""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=float, default=20e6, help="points (default 20 M)")
    p.add_argument("--files", type=int, default=5, help="input tiles (default 5)")
    p.add_argument("--tile-size", type=float, default=2000.0, help="edge of the output tiles (default 2000)")
    p.add_argument("--workers", type=int, default=2, help="workers of the run and processes of the floors")
    p.add_argument("--workdir", default="/tmp/cloudsieve-bench-floors", help="scans are cached here")
    args = p.parse_args(argv)
    n, w = int(args.size), args.workers
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    folder = make(n, work / f"tiles{n}-{args.files}", files=args.files)
    inputs = sorted(str(f) for f in folder.iterdir() if f.suffix == ".laz")
    out = work / "out"
    shutil.rmtree(out, ignore_errors=True)
    before = load()
    s = cli([str(folder), str(out), "--tile-size", str(args.tile_size), "--ratio", "0.5", "--workers", str(w)])
    tiles = sorted(str(f) for f in out.iterdir() if f.suffix == ".laz")
    with mp.get_context("forkserver").Pool(w) as pool:
        pool.map(_warm, range(w))
        dec = pool.map(decode_seconds, inputs, chunksize=1)
        enc = pool.map(encode_seconds, tiles, chunksize=1)
    memory = subprocess.run([PY, "-c", IN_MEMORY, *inputs], capture_output=True, text=True, check=True)
    import json

    mem = json.loads(memory.stdout.strip().splitlines()[-1])
    after = load()
    sec = s["seconds"]
    decode = sum(t for t, _ in dec) / w
    encode = sum(t for t, _, _ in enc) / w
    cpu = s["cpu_seconds"]["driver"] + s["cpu_seconds"]["workers"]
    print(f"\n## {n:,} points in {args.files} LAZ tiles -> tiles of {args.tile_size:g} + index.vpc, "
          f"`--ratio 0.5 --workers {w}` (load {before} -> {after})\n")
    print(f"wall {s['wall']:.1f} s, {n / s['wall']:,.0f} points/s, CPU {cpu / n * 1e6:.2f} µs a point "
          f"(driver {s['cpu_seconds']['driver']:.1f} s, workers {s['cpu_seconds']['workers']:.1f} s), "
          f"partition {sec['partition'] / s['wall']:.1%} of the run, kept {s['kept']:,}\n")
    print("| stage | wall s | floor s | × floor | floor |")
    print("|---|---:|---:|---:|---|")
    print(f"| ingest | {sec['ingest']:.1f} | {decode:.1f} | {sec['ingest'] / decode:.2f} | laspy + lazrs decode, "
          f"{sum(k for _, k in dec):,} points, {w} processes |")
    print(f"| partition + cells | {sec['partition'] + sec['cells']:.1f} | {mem['seconds']:.1f} | "
          f"{(sec['partition'] + sec['cells']) / mem['seconds']:.2f} | `simplify_points` in memory, same points "
          f"({mem['kept']:,} kept, CPU {mem['cpu']:.1f} s) |")
    print(f"| export | {sec['export']:.1f} | {encode:.1f} | {sec['export'] / encode:.2f} | laspy + lazrs encode, "
          f"{sum(k for _, k, _ in enc):,} points, {w} processes |")
    cpu_export, cpu_encode = s["stage_cpu"]["export"], sum(c for _, _, c in enc)
    print(f"| export, workers' CPU | {cpu_export:.1f} | {cpu_encode:.1f} | {cpu_export / cpu_encode:.2f} | the encode "
          f"tasks' CPU summed |")
    print(f"| merge | {sec['merge']:.1f} | | | |")
    print(f"| run | {s['wall']:.1f} | | | stages {', '.join(f'{k} {v:.1f}' for k, v in sec.items())} |")
    shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
