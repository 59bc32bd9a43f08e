"""Ingest/export throughput and peak memory on generated LAZ scans; prints a Markdown table.

    .venv/bin/python benchmarks/io.py                    # 5 M and 20 M points
    .venv/bin/python benchmarks/io.py --sizes 1e6,2e6    # smaller

For each size a realistic LAZ scan is generated (benchmarks/make_scan.py,
tiles of the real autzen_trim.laz; cached in --workdir), then each of these
runs in a fresh Python process, which reports its wall time and its own peak
resident memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``):

* laspy: laspy's own chunked LAZ decode (``chunk_iterator``, lazrs with
  parallel decompression, same chunk size) - the reference speed;
* ingest: ``cloudsieve.store.ingest`` LAZ -> zarr point store;
* export: ``cloudsieve.store.export`` store -> LAZ (all points).

Goals: ingest >= 80% of laspy's decode speed; peak RSS < 1 GB and
within 20% between the smallest and the largest size (flat in N).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, resource, sys, time
kind, src, dst, chunk = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
import laspy, zarr, numpy  # imports are not timed
from cloudsieve.store import export, ingest
from cloudsieve.store import PointStore
t0 = time.perf_counter()
c0 = resource.getrusage(resource.RUSAGE_SELF)
if kind == "laspy":
    n = 0
    with laspy.open(src, laz_backend=laspy.LazBackend.detect_available()) as reader:
        for points in reader.chunk_iterator(chunk):
            n += len(points)
elif kind == "ingest":
    n = ingest(src, dst, chunk_size=chunk, overwrite=True).count
elif kind == "export":
    store = PointStore.open(src)
    export(store, dst, chunk_size=chunk, overwrite=True)
    n = store.count
elapsed = time.perf_counter() - t0
c1 = resource.getrusage(resource.RUSAGE_SELF)
rss = c1.ru_maxrss * 1024  # kB on Linux
cpu = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
print(json.dumps({"n": n, "seconds": elapsed, "rss": rss, "cpu": cpu}))
"""


def run_child(kind: str, src: str, dst: str, chunk: int) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, kind, src, dst, str(chunk)], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="5e6,2e7", help="comma separated point counts (default 5e6,2e7)")
    p.add_argument("--workdir", default="/tmp/cloudsieve-bench-io", help="folder for scans and stores (kept between runs)")
    p.add_argument("--chunk-size", type=int, default=1_000_000)
    p.add_argument("--repeat", type=int, default=1, help="runs per measurement; the fastest is reported (default 1)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    rows = []
    for n in sizes:
        scan = work / f"scan_{n}_{args.seed}.laz"
        if not scan.exists():
            t = time.perf_counter()
            subprocess.run([sys.executable, str(HERE / "make_scan.py"), str(n), str(scan), "--seed", str(args.seed)], check=True)
            print(f"generated {scan} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
        store = work / f"store_{n}.zarr"
        out = work / f"out_{n}.laz"
        res = {}
        for kind, src, dst in (("laspy", scan, "-"), ("ingest", scan, store), ("export", store, out)):
            best = None
            for _ in range(args.repeat):
                r = run_child(kind, str(src), str(dst), args.chunk_size)
                assert r["n"] == n, (kind, r)
                if best is None or r["seconds"] < best["seconds"]:
                    best = {**r, "rss": max(r["rss"], best["rss"]) if best else r["rss"]}
            res[kind] = best
            print(
                f"{n:>11,} {kind:<7} {n / best['seconds'] / 1e6:6.2f} M pts/s  cpu {best['cpu']:6.1f} s  "
                f"wall {best['seconds']:6.1f} s  peak RSS {best['rss'] / 2**20:6.0f} MiB",
                file=sys.stderr,
            )
        res["size_mb"] = scan.stat().st_size / 1e6
        res["store_mb"] = sum(f.stat().st_size for f in store.rglob("*") if f.is_file()) / 1e6
        rows.append((n, res))
        shutil.rmtree(store, ignore_errors=True)
        out.unlink(missing_ok=True)
    load1 = os.getloadavg()

    print(f"Chunk size {args.chunk_size:,} points; {os.cpu_count()} cores; load average {load0[0]:.1f} before, {load1[0]:.1f} after.\n")
    print(
        "| points | LAZ MB | store MB | laspy decode (pts/s) | ingest (pts/s) | ingest / laspy | "
        "CPU s laspy / ingest | ingest peak RSS | export LAZ (pts/s) | export peak RSS |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n, r in rows:
        lp, ing, exp = (n / r[k]["seconds"] for k in ("laspy", "ingest", "export"))
        print(
            f"| {n:,} | {r['size_mb']:.0f} | {r['store_mb']:.0f} | {lp / 1e6:.2f} M | {ing / 1e6:.2f} M | {ing / lp:.0%} | "
            f"{r['laspy']['cpu']:.1f} / {r['ingest']['cpu']:.1f} | "
            f"{r['ingest']['rss'] / 2**20:.0f} MiB | {exp / 1e6:.2f} M | {r['export']['rss'] / 2**20:.0f} MiB |"
        )
    if len(rows) > 1:
        for kind in ("ingest", "export"):
            a, b = rows[0][1][kind]["rss"], rows[-1][1][kind]["rss"]
            print(f"\n{kind}: peak RSS {rows[-1][0]:,} / {rows[0][0]:,} points = {b / a:.2f} (goal: within 1.20)", end="")
        print()
    worst = max(r[k]["rss"] for _, r in rows for k in ("ingest", "export"))
    ratio = min((n / r["ingest"]["seconds"]) / (n / r["laspy"]["seconds"]) for n, r in rows)
    print(f"\nGoals: peak RSS < 1 GiB: {'yes' if worst < 2**30 else 'NO'} ({worst / 2**20:.0f} MiB); "
          f"ingest >= 80% of laspy decode: {'yes' if ratio >= 0.8 else 'NO'} ({ratio:.0%}).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
