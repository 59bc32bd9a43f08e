"""Small inputs: in memory against the work store in this process and the local process pool; a Markdown table.

    .venv/bin/python benchmarks/small.py                          # 1 M, 3 M and 5 M points, 2 runs each
    .venv/bin/python benchmarks/small.py --sizes 1000000 --repeat 3

For each make_scan LAZ (built once in ``--workdir``; ``autzen`` is the real
autzen_trim.laz), ``cloudsieve simplify FILE OUT --ratio 0.5`` runs in a
fresh process three ways, alternating: the default (in memory, without a
work store, up to ``cloudsieve.engine.small.IN_MEMORY_POINTS``), with
``--scheduler sync`` (the work store, every task in this process) and with
``--scheduler processes`` (the work store and the local process pool). Each
row: the wall time, the peak RSS of the process tree (sampled), and the load
average before the run; the three outputs must be the same bytes.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from engine import run_simplify, scan  # benchmarks/engine.py, beside this script

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
WAYS = (("in memory", ()), ("work store, this process", ("--scheduler", "sync")),
        ("work store, process pool", ("--scheduler", "processes")))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000000,3000000,5000000",
                    help="comma-separated point counts of make_scan files, or 'autzen' (default 1 M, 3 M, 5 M)")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each way per size (default 2)")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "cloudsieve-bench-engine"),
                    help="folder for the scans (kept: built once) and the outputs")
    args = ap.parse_args(argv)
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    print(f"# small inputs: in memory and through the work store, {os.cpu_count()} cores\n")
    print("| points | run | wall (s) | peak RSS (MiB) | scheduler | load |")
    print("|---:|---|---|---|---|---|")
    for size in args.sizes.split(","):
        src = DATA / "autzen_trim.laz" if size == "autzen" else scan(int(size), work)
        rows = {name: ([], [], "") for name, _ in WAYS}
        points = 0
        outputs = set()
        for _ in range(args.repeat):
            for i, (name, extra) in enumerate(WAYS):
                load = os.getloadavg()[0]
                dst = work / f"small_{i}.laz"
                s = run_simplify(src, dst, "--ratio", "0.5", *extra)
                walls, peaks, _ = rows[name]
                walls.append((s["wall"], load))
                peaks.append(s["tree_peak"] / 2**20)
                rows[name] = (walls, peaks, s["scheduler"])
                points = s["points_in"]
                outputs.add(dst.read_bytes())
        if len(outputs) != 1:
            print(f"the three ways wrote different files for {src}", file=sys.stderr)
            return 1
        for name, (walls, peaks, sched) in rows.items():
            times = ", ".join(f"{w:.2f}" for w, _ in walls)
            loads = "–".join(f"{lo:.1f}" for lo in (min(x for _, x in walls), max(x for _, x in walls)))
            print(f"| {points:,} | {name} | {times} | {max(peaks):,.0f} | {sched} | {loads} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
