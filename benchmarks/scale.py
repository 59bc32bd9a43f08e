"""Benchmark of scale-out: ingest and export as tasks, the driver's share, tiles in and out.

    .venv/bin/python benchmarks/scale.py                          # 6 M points, then 100 M in 25 tiles (long)
    .venv/bin/python benchmarks/scale.py --size 1e6 --big 4e6 --files 4   # a quick look

Prints Markdown tables, each with the load average before and after:

1. **ingest + export, 1 vs 2 workers** on one LAZ of ``--size`` points:
   ``cloudsieve.store.ingest`` and ``export`` (every point) through a
   :class:`~cloudsieve.engine.runner.Runner` of 1 or 2 local worker
   processes, each configuration in a fresh process; wall time per stage,
   the driver's CPU and the workers' CPU, the driver's peak RSS; the
   speed-up of 2 workers over 1. The store's bytes per point beside LAZ's.
2. **the driver's share** of a default ``cloudsieve simplify --ratio 0.5``
   run with 2 workers on the same file: ``cpu_seconds`` of ``--json``, and
   the driver process's peak RSS (sampled, that process alone).
3. **a tiled delivery**: ``--big`` points written as ``--files`` LAZ tiles
   (``benchmarks/make_scan.py --files``), simplified as one cloud (SRC the
   folder) to one LAZ, to tiles + index.vpc (``--tile-size``) and to one
   COPC, each a CLI run: wall time, points/s, peak RSS of the process tree
   and of the driver alone, CPU split.

Scans are cached in ``--workdir``. Never run two benchmarks at once.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
sys.path.insert(0, str(ROOT / "benchmarks"))

from engine import TreePeak  # noqa: E402  (the process-tree sampler of benchmarks/engine.py)

_CHILD = r"""
import json, resource, sys, time
from cloudsieve.engine.runner import Runner
from cloudsieve.store import export, ingest
src, store, dst, workers = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
run = Runner("processes", workers)
run(abs, [(-1,)] * workers, "warm")  # the workers started (not part of either stage)
c0, t0 = time.process_time(), time.perf_counter()
st = ingest(src, store, run=run)
t1 = time.perf_counter()
export(st, dst, run=run)
t2 = time.perf_counter()
out = {"ingest": t1 - t0, "export": t2 - t1, "driver_cpu": time.process_time() - c0, "workers_cpu": run.worker_cpu(),
       "driver_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, "count": st.count}
run.close()
print(json.dumps(out))
"""


def load() -> str:
    return "/".join(f"{v:.2f}" for v in os.getloadavg())


def du(path: Path) -> int:
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def make(n: int, out: Path, files: int = 1) -> Path:
    if not out.exists():
        cmd = [PY, str(ROOT / "benchmarks" / "make_scan.py"), str(n), str(out)]
        if files > 1:
            cmd += ["--files", str(files)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return out


def io_run(src: Path, workdir: Path, workers: int) -> dict:
    store, dst = workdir / "io.zarr", workdir / "io-out.laz"
    shutil.rmtree(store, ignore_errors=True)
    dst.unlink(missing_ok=True)
    out = subprocess.run([PY, "-c", _CHILD, str(src), str(store), str(dst), str(workers)], check=True,
                         capture_output=True, text=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["store_bytes"] = du(store)
    shutil.rmtree(store, ignore_errors=True)
    dst.unlink(missing_ok=True)
    return res


class DiskPeak:
    """The most disk a run takes on *path*'s file system: free space at the start minus its lowest, sampled."""

    def __init__(self, path: Path, interval: float = 1.0) -> None:
        self.path, self.start, self.low = path, shutil.disk_usage(path).free, shutil.disk_usage(path).free
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, args=(interval,), daemon=True)
        self._t.start()

    def _loop(self, interval: float) -> None:
        while not self._stop.wait(interval):
            self.low = min(self.low, shutil.disk_usage(self.path).free)

    def stop(self) -> int:
        self._stop.set()
        self._t.join()
        return self.start - min(self.low, shutil.disk_usage(self.path).free)


def cli(args: list[str], workdir: Path | None = None, prefix: list[str] | None = None) -> dict:
    """One ``cloudsieve simplify ... --json`` run: its summary, wall time, tree and driver peak RSS, and the
    peak disk it took on *workdir*'s file system when given (other writers on it count too); *prefix* runs it
    under a wrapper such as ``taskset -c 0``."""
    cmd = [*(prefix or []), PY, "-m", "cloudsieve", "simplify", *args, "--overwrite", "--json", "--no-progress"]
    t0 = time.perf_counter()
    disk = DiskPeak(workdir) if workdir is not None else None
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tree, alone = TreePeak(proc.pid), TreePeak(proc.pid, children=False)
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    summary_disk = disk.stop() if disk is not None else None
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{err[-3000:]}")
    summary = json.loads(out)
    summary.update(wall=wall, tree_peak=tree.stop(), driver_peak=alone.stop(), disk_peak=summary_disk)
    return summary


def mib(n: float) -> str:
    return f"{n / 2**20:,.0f} MiB"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=float, default=6e6, help="points of the one-file runs (default 6e6)")
    p.add_argument("--big", type=float, default=1e8, help="points of the tiled delivery (default 1e8)")
    p.add_argument("--files", type=int, default=25, help="tiles of the delivery (default 25)")
    p.add_argument("--tile-size", type=float, default=2000.0, help="edge of the output tiles (default 2000)")
    p.add_argument("--workdir", default="/tmp/cloudsieve-bench-scale")
    p.add_argument("--skip", default="", help="comma list of sections to skip: io,share,tiles")
    p.add_argument("--outputs", default="laz,tiles,copc", help="outputs of the tiled delivery (default laz,tiles,copc)")
    args = p.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    n = int(args.size)
    src = make(n, work / f"scan{n}.laz")
    print(f"# scale-out benchmark ({os.cpu_count()} cores)\n")

    if "io" not in skip:
        print(f"## ingest + export as tasks, {n:,} points (load before {load()})\n")
        print("| workers | ingest s | export s | total s | driver CPU s | workers CPU s | driver peak RSS |")
        print("|---:|---:|---:|---:|---:|---:|---:|")
        res = {}
        for w in (1, 2):
            r = res[w] = io_run(src, work, w)
            print(f"| {w} | {r['ingest']:.2f} | {r['export']:.2f} | {r['ingest'] + r['export']:.2f} | "
                  f"{r['driver_cpu']:.2f} | {r['workers_cpu']:.2f} | {mib(r['driver_rss'])} |")
        t1, t2 = (res[w]["ingest"] + res[w]["export"] for w in (1, 2))
        print(f"\n2 workers over 1: **{t1 / t2:.2f}x** (load after {load()}). Store: "
              f"{res[2]['store_bytes'] / n:.2f} bytes a point; the LAZ: {src.stat().st_size / n:.2f}.\n")

    if "share" not in skip:
        print(f"## the driver's share of `simplify --ratio 0.5 --workers 2`, {n:,} points (load before {load()})\n")
        s = cli([str(src), str(work / "share.laz"), "--ratio", "0.5", "--workers", "2"])
        cpu = s["cpu_seconds"]
        share = cpu["driver"] / max(1e-9, cpu["driver"] + cpu["workers"])
        stages = ", ".join(f"{k} {v:.1f}" for k, v in s["seconds"].items() if k != "total")
        print("| wall s | stages s | driver CPU s | workers CPU s | driver share | driver peak RSS | tree peak RSS |")
        print("|---:|---|---:|---:|---:|---:|---:|")
        print(f"| {s['wall']:.1f} | {stages} | {cpu['driver']:.1f} | {cpu['workers']:.1f} | {100 * share:.1f}% | "
              f"{mib(s['driver_peak'])} | {mib(s['tree_peak'])} |")
        print(f"\n(load after {load()})\n")

    if "tiles" not in skip:
        big = int(args.big)
        folder = make(big, work / f"tiles{big}-{args.files}", files=args.files)
        print(f"## {big:,} points in {args.files} LAZ tiles, simplified as one cloud (`--ratio 0.5`, "
              f"2 workers; load before {load()})\n")
        print("| output | wall s | points/s | stages s | CPU driver / workers s | driver peak RSS | tree peak RSS | "
              "peak disk | output |")
        print("|---|---:|---:|---|---|---:|---:|---:|---:|")
        outs = {"laz": ("one LAZ", [str(work / "big.laz")]),
                "tiles": (f"tiles of {args.tile_size:g} + index.vpc", [str(work / "big-tiles"), "--tile-size",
                                                                         str(args.tile_size)]),
                "copc": ("one COPC", [str(work / "big.copc.laz")])}
        for name, dst in (outs[k] for k in args.outputs.split(",") if k):
            try:
                s = cli([str(folder), *dst, "--ratio", "0.5", "--workers", "2"], work)
            except RuntimeError as exc:
                print(f"| {name} | failed: {str(exc).splitlines()[-1][:120]} | | | | | | | |")
                continue
            cpu = s["cpu_seconds"]
            stages = ", ".join(f"{k} {v:.1f}" for k, v in s["seconds"].items() if k != "total")
            print(f"| {name} | {s['wall']:.1f} | {big / s['wall']:,.0f} | {stages} | {cpu['driver']:.1f} / "
                  f"{cpu['workers']:.1f} | {mib(s['driver_peak'])} | {mib(s['tree_peak'])} | {mib(s['disk_peak'])} | "
                  f"{mib(du(Path(dst[0])) if Path(dst[0]).is_dir() else Path(dst[0]).stat().st_size)} |", flush=True)
        print(f"\n(load after {load()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
