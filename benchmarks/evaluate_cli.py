"""``benchmarks/evaluate.py --end-to-end N``: the evaluation as a user runs it, on an N-point scan.

make_scan.py -> ``cloudsieve simplify --ratio 0.5`` -> ``cloudsieve evaluate --report`` (default options)
-> report.html in headless Chromium. Every figure is printed with the load average (1, 5, 15 min) at the
time it was measured: the machine is shared.
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
          "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars"]


def load() -> str:
    return "/".join(f"{v:.2f}" for v in os.getloadavg())


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "cloudsieve", *args]


def run_measured(cmd: list[str]) -> tuple[float, int, str]:
    """(wall seconds, peak RSS of the process and its children in bytes, stdout) of *cmd*."""
    import psutil

    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak, done = [0], threading.Event()

    def sample():
        root = psutil.Process(proc.pid)
        while not done.is_set():
            total = 0
            try:
                for p in [root, *root.children(recursive=True)]:
                    try:
                        total += p.memory_info().rss
                    except psutil.Error:
                        pass
            except psutil.Error:
                break
            peak[0] = max(peak[0], total)
            done.wait(0.1)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    out, err = proc.communicate()
    done.set()
    th.join()
    wall = time.perf_counter() - t
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{err[-3000:]}")
    return wall, peak[0], out


def chromium_times(url: str, runs: int = 3) -> tuple[list[float], list[float]]:
    """(wall seconds of ``chromium --headless --dump-dom URL``, the page's renderMs / 1000) per run."""
    walls, renders = [], []
    for i in range(runs):
        with tempfile.TemporaryDirectory() as profile:
            t = time.perf_counter()
            r = subprocess.run([CHROMIUM, *_FLAGS, f"--user-data-dir={profile}", "--dump-dom", url],
                               capture_output=True, text=True, timeout=300, check=False)
            walls.append(time.perf_counter() - t)
        m = re.search(r'data-render-ms="(\d+)"', r.stdout)
        if m:
            renders.append(int(m.group(1)) / 1000)
    return walls, renders


def _median(v: list[float]) -> str:
    return f"{statistics.median(v):.2f} (runs {', '.join(f'{x:.2f}' for x in v)})" if v else "-"


def end_to_end(n: int, workdir: Path) -> int:
    workdir.mkdir(parents=True, exist_ok=True)
    scan, simp, rep = workdir / f"scan{n}.laz", workdir / f"scan{n}-50.laz", workdir / f"report{n}"
    print(f"## Evaluation end to end: {n:,}-point scan, {os.cpu_count()} cores\n", flush=True)
    if not scan.exists():
        t = time.perf_counter()
        subprocess.run([sys.executable, str(ROOT / "benchmarks" / "make_scan.py"), str(n), str(scan)], check=True,
                       capture_output=True)
        print(f"make_scan: {time.perf_counter() - t:.1f} s (load {load()})", file=sys.stderr, flush=True)
    if not simp.exists():
        wall, peak, _ = run_measured(_cli("simplify", str(scan), str(simp), "--ratio", "0.5"))
        print(f"simplify --ratio 0.5: {wall:.1f} s, peak {peak / 2**20:.0f} MiB (load {load()})",
              file=sys.stderr, flush=True)
    print("| figure | value | load average (1/5/15 min) when measured |")
    print("|---|---:|---|", flush=True)
    before = load()
    wall, peak, _ = run_measured(_cli("evaluate", str(scan), str(simp), "--report", str(rep), "--no-progress"))
    after = load()
    report = json.loads((rep / "report.json").read_text())
    timing, sf, ps = report["timing"], report.get("surface") or {}, report["psnr"]
    smp = sf.get("sampling") or {}
    lab = f"{before} before, {after} after"
    print(f"| `cloudsieve evaluate` wall time, whole command (s) | {wall:.1f} | {lab} |")
    print(f"| point level (s): D1 + Chamfer exact, D2 on {ps.get('d2_sample', {}).get('forward') or 'every'} "
          f"points a direction | {timing['point']:.1f} | {lab} |")
    if sf:
        print(f"| surface level (s): {len(sf['tiles'])} random tiles of <= {sf['tile_points']:,} points "
              f"({100 * smp.get('points_share', 0):.2f}% of the points), budget {smp.get('budget', '-')} s | "
              f"{timing['surface']:.1f} | {lab} |")
    print(f"| evaluation (point + surface, report.json's total) (s) | {timing['total']:.1f} | {lab} |")
    print(f"| report files, imports and start (s) | {wall - timing['total']:.1f} | {lab} |")
    print(f"| peak memory, evaluate and its children (MiB) | {peak / 2**20:.0f} | {lab} |")
    html = rep / "report.html"
    print(f"| report.html size (MB) | {html.stat().st_size / 1e6:.2f} | - |", flush=True)
    lb = load()
    blank_w, _ = chromium_times("about:blank")
    page_w, renders = chromium_times(html.as_uri())
    la = load()
    print(f"| report.html: navigation to first frame, the page's own clock (s, median of 3) | {_median(renders)} | "
          f"{lb} before, {la} after |")
    print(f"| `chromium --headless --dump-dom report.html`, wall (s, median of 3) | {_median(page_w)} | "
          f"{lb} before, {la} after |")
    print(f"| `chromium --headless --dump-dom about:blank`, wall: the browser alone (s, median of 3) | "
          f"{_median(blank_w)} | {lb} before, {la} after |")
    if sf.get("forward"):
        sp = smp.get("spread") or {}
        se = (sp.get("forward") or {}).get("mean_pct_se")
        print(f"\nSurface: Metro forward mean {sf['forward']['mean_pct']:.4g}% of the diagonal"
              + (f" ± {se:.2g} (standard error over {len(sf['tiles'])} tiles)" if se is not None else "")
              + f"; tiles sized at {smp.get('rate', 0):.0f} points/s; per tile (points, s): "
              + ", ".join(f"{t['points_original']:,}/{t['seconds']:.1f}" for t in sf["tiles"]))
    d2se = ps.get("d2_se_db") or {}
    print(f"D1 PSNR forward {ps['d1']['forward']:.2f} dB (exact); D2 PSNR forward {ps['d2']['forward']:.2f} dB"
          + (f" ± {d2se['forward']:.3f} (standard error, sample of {ps['d2_sample']['forward']:,})"
             if d2se.get("forward") else ""))
    return 0
