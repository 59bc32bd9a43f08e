"""Core benchmark: the paper's setting on real scans, and throughput at 1 M / 5 M points.

Run: ``.venv/bin/python benchmarks/core.py [--sizes 1e6,5e6] [--fcm-iters 20] [--workers N] [--skip-paper]``

(a) bun_zipper.ply and maxplanck.ply (vertices as the cloud), clusters of ~400
    points, S = 0.001, KM and FCM, rule ``threshold`` (the paper) and
    ``iterative`` (the default): points kept, % removed, seconds per stage,
    against the paper's MATLAB times (7,752 s KM / 7,357 s FCM for 49,089
    points). Our maxplanck.ply has 25,445 vertices, not the paper's 49,089.
(b) a generated surface (a height field with small noise) of each size:
    points/s of refinement (KM to convergence and to simplify's default
    stop; FCM for ``--fcm-iters`` iterations, also given per iteration, and
    to simplify's default stop), of one scoring pass, and of each
    rule on the KM clusters (points/s = input points / seconds of the whole
    call; the round rules give their number of rounds), and of ``eliminate``
    (the default rule; no clusters) at 50% and 10%; and the peak memory
    of KM at 1 M points into 2,500 clusters (a fresh process, so the figure
    is the process's peak RSS).

``--workers`` is the number of threads of the k-d tree queries (default: all
cores), passed to every stage.

Prints Markdown tables. Timings are wall-clock on whatever else runs on the
machine.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from cloudsieve.core import ConvergenceWarning, FuzzyCMeans, KMeans
from cloudsieve.core.entropy import score_points
from cloudsieve.core import prune
from cloudsieve.core.eliminate import eliminate
from cloudsieve.core.refine import REFINE_FCM_MAX_ITER, REFINE_KM_TOL, REFINE_LABEL_TOL

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def read_vertices(path: Path) -> np.ndarray:
    try:
        from cloudsieve.io import read_cloud
    except ImportError:  # minimal ASCII PLY reader
        lines = path.read_text().splitlines()
        nv = next(int(s.split()[2]) for s in lines if s.startswith("element vertex"))
        start = lines.index("end_header") + 1
        return np.array([list(map(float, s.split()[:3])) for s in lines[start : start + nv]])
    return read_cloud(str(path))[0]


def surface(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2)) * 100.0
    z = 5.0 * np.sin(u[:, 0] / 7.0) * np.cos(u[:, 1] / 11.0) + 0.01 * rng.standard_normal(n)
    return np.c_[u, z]


WORKERS = None  # k-d tree threads for every stage (--workers)


def fit(method: str, pts: np.ndarray, c: int, **kw):
    est = KMeans(c, **kw) if method == "km" else FuzzyCMeans(c, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        t = time.perf_counter()
        est.fit(pts, threads=WORKERS)
        return est, time.perf_counter() - t


def paper_table(fcm_max_iter: int) -> str:
    rows = [
        "| model | points | clusters | method | refinement stop | rule | kept | removed % | refine s (iters) | score s | rule s | total s | paper s |",
        "|---|---:|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    paper = {"km": "7,752.49 (49,089 pts)", "fcm": "7,356.52 (49,089 pts)"}
    for name in ("bun_zipper.ply", "maxplanck.ply"):
        path = DATA / name
        if not path.is_file():
            rows.append(f"| {name} | missing | | | | | | | | | | |")
            continue
        pts = read_vertices(path)
        n = len(pts)
        c = math.ceil(n / 400)
        settings = [("km", "paper: no change", {}), ("km", f"default: {REFINE_KM_TOL:.0%} change", {"tol": REFINE_KM_TOL}),
                    ("fcm", f"paper: tol 1e-5, max {fcm_max_iter}", {"max_iter": fcm_max_iter}),
                    ("fcm", f"default: {REFINE_LABEL_TOL:.0%} labels change, max {REFINE_FCM_MAX_ITER}",
                     {"max_iter": REFINE_FCM_MAX_ITER, "label_tol": REFINE_LABEL_TOL})]
        for method, stop, kw in settings:
            est, t_ref = fit(method, pts, c, **kw)
            labels = est.labels_
            t = time.perf_counter()
            score_points(pts, labels, threads=WORKERS)
            t_sc = time.perf_counter() - t
            for rule in ("threshold", "iterative"):
                t = time.perf_counter()
                keep = prune(pts, labels, rule=rule, threshold=1e-3, threads=WORKERS)
                t_rule = time.perf_counter() - t
                kept = int(keep.sum())
                conv = "" if est.converged_ else ", not converged"
                rows.append(
                    f"| {name} | {n:,} | {c} | {method.upper()} | {stop} | {rule} | {kept:,} | {100 * (n - kept) / n:.2f} | "
                        f"{t_ref:.2f} ({est.n_iter_}{conv}) | {t_sc:.3f} | {t_rule:.3f} | {t_ref + t_rule:.2f} | {paper[method]} |"
                )
    return "\n".join(rows)


def throughput_table(sizes, fcm_iters: int):
    """Yields the table's rows as they are measured."""
    yield "| points | stage | seconds | points/s | note |"
    yield "|---:|---|---:|---:|---|"
    rows = _Rows()
    for n in sizes:
        pts = surface(n)
        c = math.ceil(n / 400)
        est, t = fit("km", pts, c)
        rows.append(f"| {n:,} | refine KM ({c:,} clusters) | {t:.2f} | {n / t:,.0f} | {est.n_iter_} iterations"
                    f"{'' if est.converged_ else ' (max_iter)'} to no change |")
        labels = est.labels_
        yield from rows.take()
        e2, t = fit("km", pts, c, tol=REFINE_KM_TOL)
        rows.append(f"| {n:,} | refine KM ({c:,} clusters) | {t:.2f} | {n / t:,.0f} | {e2.n_iter_} iterations"
                    f" to at most {REFINE_KM_TOL:.0%} changing (simplify's default) |")
        f, t = fit("fcm", pts, c, max_iter=fcm_iters)
        yield from rows.take()
        rows.append(f"| {n:,} | refine FCM, {f.n_iter_} iterations | {t:.2f} | {n / t:,.0f} | "
                    f"{n * f.n_iter_ / t:,.0f} point-iterations/s{'' if f.converged_ else '; not converged'} |")
        yield from rows.take()
        f, t = fit("fcm", pts, c, max_iter=REFINE_FCM_MAX_ITER, label_tol=REFINE_LABEL_TOL)
        rows.append(f"| {n:,} | refine FCM, {f.n_iter_} iterations | {t:.2f} | {n / t:,.0f} | to at most "
                    f"{REFINE_LABEL_TOL:.0%} hard labels changing, max {REFINE_FCM_MAX_ITER} (simplify's default) |")
        yield from rows.take()
        t0 = time.perf_counter()
        s = score_points(pts, labels, threads=WORKERS)
        t = time.perf_counter() - t0
        rows.append(f"| {n:,} | score (one pass, KM clusters) | {t:.2f} | {n / t:,.0f} | "
                    f"{s.n_duplicates} duplicates |")
        for rule, kw in (("threshold", {}), ("iterative", {}), ("target", {"ratio": 0.5}),
                         ("iterative", {"ratio": 0.5}), ("coverage", {"ratio": 0.5})):
            rounds = []
            t0 = time.perf_counter()
            keep = prune(pts, labels, rule=rule, threads=WORKERS, progress=rounds.append, **kw)
            t = time.perf_counter() - t0
            label = rule + (" ratio 0.5" if kw else " S=0.001")
            note = f"; {len(rounds)} rounds" if rule in ("iterative", "coverage") else ""
            rows.append(f"| {n:,} | rule {label} | {t:.2f} | {n / t:,.0f} | kept {int(keep.sum()):,}{note} |")
            yield from rows.take()
        eliminate(pts[:40_000], ratio=0.5, threads=WORKERS)  # loads its kernels from numba's cache (~0.15 s)
        for ratio in (0.5, 0.1):  # the default rule (no clusters): weighted sample elimination + one relocation
            t0 = time.perf_counter()
            kept = eliminate(pts, ratio=ratio, threads=WORKERS)
            t = time.perf_counter() - t0
            rows.append(f"| {n:,} | rule eliminate ratio {ratio} (the default) | {t:.2f} | {n / t:,.0f} | "
                        f"kept {len(kept):,} |")
            yield from rows.take()


class _Rows(list):
    def take(self):
        out = list(self)
        self.clear()
        return out


def _peak_rss_kib() -> int:
    """This process's peak RSS in KiB: VmHWM, which execve resets (ru_maxrss
    keeps the parent's peak across fork + exec on Linux)."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def memory_child(method: str, n: int, c: int, iters: int) -> None:
    pts = surface(n)
    base = _peak_rss_kib()
    kw = {"max_iter": iters} if method == "fcm" else {}
    fit(method, pts, c, **kw)
    peak = _peak_rss_kib()
    print(f"{base / 1024:.0f} {peak / 1024:.0f}")


def memory_table(n: int, c: int, fcm_iters: int) -> str:
    rows = ["| run | RSS before fit (MiB, incl. the points) | peak RSS (MiB) |", "|---|---:|---:|"]
    for method in ("km", "fcm"):
        out = subprocess.run([sys.executable, __file__, "--memory-child", method, str(n), str(c), str(fcm_iters)],
                             capture_output=True, text=True, check=True).stdout.split()
        rows.append(f"| {method.upper()} {n:,} points into {c:,} clusters | {out[0]} | {out[1]} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="1e6,5e6", help="comma-separated cloud sizes for (b); empty to skip")
    ap.add_argument("--fcm-iters", type=int, default=20, help="FCM iterations timed in (b)")
    ap.add_argument("--fcm-max-iter", type=int, default=300, help="FCM max_iter in (a)")
    ap.add_argument("--workers", type=int, default=None, help="k-d tree threads (default: all cores)")
    ap.add_argument("--skip-paper", action="store_true")
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--memory-child", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    global WORKERS
    WORKERS = a.workers
    if a.memory_child:
        m, n, c, it = a.memory_child
        memory_child(m, int(n), int(c), int(it))
        return 0
    print(f"cloudsieve core benchmark, {os.cpu_count()} cores, k-d tree threads {a.workers or os.cpu_count()}, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    if not a.skip_paper:
        print("## (a) The paper's setting (S = 0.001, clusters of ~400 points)\n")
        print("maxplanck.ply here has 25,445 vertices, not the paper's 49,089 (a different model file); "
              "the paper's times are MATLAB on an i3 with 2 GB.\n")
        print(paper_table(a.fcm_max_iter), flush=True)
        print()
    sizes = [int(float(s)) for s in a.sizes.split(",") if s.strip()]
    if sizes:
        print("## (b) Throughput on a generated surface (clusters of ~400 points)\n")
        for row in throughput_table(sizes, a.fcm_iters):
            print(row, flush=True)
        print()
    if not a.skip_memory:
        print("## Memory: 1 M points into 2,500 clusters\n")
        print(memory_table(1_000_000, 2_500, a.fcm_iters))
    return 0


if __name__ == "__main__":
    sys.exit(main())
