"""Benchmark of object storage: the same tiled delivery on local disk and on S3 (SeaweedFS on loopback).

    .venv/bin/python benchmarks/cloud.py                           # 20 M points in 5 LAZ tiles
    .venv/bin/python benchmarks/cloud.py --size 2e6 --files 2      # a quick look

``--size`` points in ``--files`` LAZ tiles (``benchmarks/make_scan.py --files``) are simplified as one cloud
(``--ratio 0.5 --workers 2``) to tiles of ``--tile-size`` + index.vpc and to one LAZ, each a CLI run
(``--json``), one after the other in the same run of this script:

- **local**: tiles on local disk in, outputs on local disk, the work store on local disk;
- **s3, local store**: tiles on S3 in, outputs to S3, the work store on local disk (``--store``);
- **s3**: every path on S3, the work store too (what a shared-nothing cluster runs).

The S3 server is SeaweedFS's ``weed mini`` (``tests/s3server.py``) with its Prometheus metrics on: each run's
S3 requests by type and the bytes the server sent (reads) and received (writes) come from its counters. The
table gives wall time, points/s, the ratio to the local run, the CPU of the driver and the workers, the S3
server's own CPU (on this machine it takes the workers' cores; on a cluster it runs elsewhere), the
process tree's peak RSS (the S3 server not included), requests and bytes per input point, and the bytes
read over the input's LAZ bytes plus the work store's (both read once at best). The load average is printed
before and after. Never run two benchmarks at once.

``--server-cpus 1 --run-cpus 0 --workers 1`` puts the S3 server on CPUs of its own (``sched_setaffinity``, every
thread of weed) and the runs, local and S3 alike, on the others: the object store off the compute cores, as on
a cluster, where it runs on other machines.
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

from scale import cli, du, load, make, mib  # noqa: E402
from s3server import S3Server  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class MeteredServer(S3Server):
    """An S3Server whose Prometheus metrics (requests by type, bytes per bucket) are served on loopback, on the
    CPUs *cpus* when given (``taskset``: weed's threads inherit them)."""

    metrics_port = _free_port()
    cpus: str | None = None

    def command(self) -> list[str]:
        args = super().command()
        i = args.index("mini") + 1
        args = args[:i] + [f"-metricsPort={self.metrics_port}", "-metricsIp=127.0.0.1"] + args[i:]
        return (["taskset", "-c", self.cpus] if self.cpus else []) + args

    def counters(self, bucket: str) -> dict:
        """``{"GET": n, "PUT": n, ..., "sent": bytes, "received": bytes}`` of *bucket* so far."""
        text = urllib.request.urlopen(f"http://127.0.0.1:{self.metrics_port}/metrics", timeout=30).read().decode()
        out: dict = {"sent": 0.0, "received": 0.0}
        for line in text.splitlines():
            m = re.match(r'SeaweedFS_s3_request_total\{bucket="([^"]*)",code="[^"]*",type="([^"]+)"\} (\S+)', line)
            if m and m.group(1) == bucket:
                out[m.group(2)] = out.get(m.group(2), 0.0) + float(m.group(3))
            m = re.match(r'SeaweedFS_s3_bucket_traffic_(sent|received)_bytes_total\{bucket="([^"]*)"\} (\S+)', line)
            if m and m.group(2) == bucket:
                out[m.group(1)] += float(m.group(3))
        return out


def server_cpu(server: S3Server) -> float:
    """CPU seconds (user + system) of the S3 server's process so far: it shares the machine's cores."""
    import psutil

    t = psutil.Process(server.pid).cpu_times()
    return t.user + t.system


def delta(after: dict, before: dict) -> dict:
    return {k: after.get(k, 0.0) - before.get(k, 0.0) for k in set(after) | set(before)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=float, default=20e6, help="points (default 20 M)")
    p.add_argument("--files", type=int, default=5, help="input tiles (default 5)")
    p.add_argument("--tile-size", type=float, default=2000.0, help="edge of the output tiles (default 2000)")
    p.add_argument("--workdir", default="/tmp/cloudsieve-bench-cloud", help="scans are cached here")
    p.add_argument("--outputs", default="tiles,laz", help="outputs: tiles, laz, copc (default tiles,laz)")
    p.add_argument("--workers", type=int, default=2, help="workers of each run (default 2)")
    p.add_argument("--server-cpus", default=None, help="CPU list of the S3 server (taskset -c), e.g. 1")
    p.add_argument("--run-cpus", default=None, help="CPU list of the runs (taskset -c), e.g. 0")
    args = p.parse_args(argv)
    MeteredServer.cpus = args.server_cpus
    pin = ["taskset", "-c", args.run_cpus] if args.run_cpus else None
    n = int(args.size)
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    folder = make(n, work / f"tiles{n}-{args.files}", files=args.files)
    in_bytes = du(folder)
    print(f"load average before: {load()}")
    with MeteredServer() as server:
        bucket = "bench"
        url = server.make_bucket(bucket)
        fs = server.filesystem()
        for f in sorted(folder.iterdir()):
            fs.put_file(str(f), f"{bucket}/in/{f.name}")
        env = server.env()
        os.environ.update(env)  # the runs' object store: the standard AWS_* chain, no option
        outputs = {"tiles": ("tiles + VPC", "tl", ["--tile-size", str(args.tile_size)]),
                   "laz": ("one LAZ", "one.laz", []), "copc": ("one COPC", "one.copc.laz", [])}
        rows = []
        for key in [o.strip() for o in args.outputs.split(",") if o.strip()]:
            label, name, extra = outputs[key]
            local_store = work / "cloud-work.zarr"
            runs = {
                "local": ([str(folder), str(work / f"cloud-{name}")], ["--store", str(local_store)]),
                "s3, local store": ([f"{url}/in/", f"{url}/a/{name}"], ["--store", str(local_store)]),
                "s3": ([f"{url}/in/", f"{url}/b/{name}"], ["--store", f"{url}/work-{key}.zarr"]),
            }
            base = None
            for where, (paths, store) in runs.items():
                before = server.counters(bucket)
                t0, weed0 = load(), server_cpu(server)
                s = cli([*paths, "--ratio", "0.5", "--workers", str(args.workers), *store, *extra], prefix=pin)
                moved = delta(server.counters(bucket), before)
                weed = server_cpu(server) - weed0
                if where == "s3":
                    fs.invalidate_cache()
                    store_bytes = sum(fs.du(f"{bucket}/work-{key}.zarr", total=False).values())
                else:
                    store_bytes = du(local_store)
                base = base or s["wall"]
                cpu = s["cpu_seconds"]
                requests = sum(v for k, v in moved.items() if k not in ("sent", "received"))
                read_over = moved["sent"] / (in_bytes + (store_bytes if where == "s3" else 0)) if where != "local" else 0
                rows.append((label, where, s["wall"], n / s["wall"], s["wall"] / base, cpu["driver"], cpu["workers"],
                             cpu["driver"] / max(cpu["driver"] + cpu["workers"], 1e-9), s["tree_peak"], requests / n,
                             moved["sent"] / n, moved["received"] / n, read_over, store_bytes,
                             {k: int(v) for k, v in sorted(moved.items()) if k not in ("sent", "received") and v},
                             f"{t0} -> {load()}", weed))
                subprocess.run(["rm", "-rf", str(local_store)], check=False)
    where_cpus = (f"; runs on CPUs {args.run_cpus}, the S3 server on CPUs {args.server_cpus}"
                  if args.run_cpus or args.server_cpus else "")
    print(f"\n## {n:,} points in {args.files} LAZ tiles ({mib(in_bytes)}), `--ratio 0.5 --workers {args.workers}`"
          f"{where_cpus}\n")
    print("| output | where | wall | points/s | × local | driver CPU | workers CPU | driver share | S3 server CPU | "
          "tree peak | requests/point | bytes read/point | bytes written/point | read / (input + store) | store | "
          "requests | load |")
    print("|" + "---|" * 17)
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]:.1f} s | {r[3]:,.0f} | {r[4]:.2f} | {r[5]:.1f} s | {r[6]:.1f} s | "
              f"{r[7]:.1%} | {r[16]:.1f} s | {mib(r[8])} | {r[9]:.2e} | {r[10]:.2f} | {r[11]:.2f} | "
              f"{r[12]:.2f} | {mib(r[13])} | {r[14]} | {r[15]} |")
    print(f"\nload average after: {load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
