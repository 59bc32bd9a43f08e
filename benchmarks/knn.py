"""The exact k-NN query that scoring needs, in the libraries at hand.

Run: ``.venv/bin/python benchmarks/knn.py [--n 1000000] [--k 20]``

The points of a generated surface (``core.surface``) in K-means clusters of
~400 (the refinement's default stop), each cluster's id times a gap as a 4th
coordinate, exactly as ``entropy._knn_query`` builds its one tree; every point
queries its k + 2 nearest (itself, k, and the (k+1)-th). Timed, best of 3,
k-d tree threads = cores: scipy's cKDTree (what cloudsieve uses), Open3D's
``core.nns.NearestNeighborSearch`` (a dependency already), and pykdtree when
it is importable (not a dependency; its threads follow OMP_NUM_THREADS).
Prints a Markdown table with points/s of the query alone: the ceiling of the
scoring stage's throughput. Beside them, cloudsieve's numba kernel
(``core.kernels.knn.knn_in_clusters``: the same query inside each cluster,
tree build included, with cores threads and with one), compiled before the
timing; then its first-call compile time in fresh processes, without numba's
cache (an empty ``NUMBA_CACHE_DIR``) and with it (the same directory again).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from core import surface  # noqa: E402

from cloudsieve.core import KMeans  # noqa: E402
from cloudsieve.core.kernels.knn import knn_in_clusters  # noqa: E402
from cloudsieve.core.knn import with_cluster_coordinate  # noqa: E402
from cloudsieve.core.refine import REFINE_LABEL_TOL  # noqa: E402


def best(fn, reps=3):
    out, ts = None, []
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return min(ts), out


FIRST_CALL = """
import time
t = time.perf_counter()
import numpy as np
from cloudsieve.core.kernels.knn import knn_in_clusters
from cloudsieve.core.kernels.entropy import entropy_gain
from cloudsieve.core.kernels.radius import within_radius
t1 = time.perf_counter()
P = np.random.default_rng(0).random((200, 3))
d, nb = knn_in_clusters(P, [0, 100, 200], 11)
t2 = time.perf_counter()
rows, cl, kr = np.arange(200), np.repeat([0, 1], 100), np.full(200, 10)
entropy_gain(rows, cl, 2, d[:, 9], d[:, 10], nb, kr, 3, 200)
t3 = time.perf_counter()
within_radius(P, [0, 100, 200], 0.2)
t4 = time.perf_counter()
print(t1 - t, t2 - t1, t3 - t2, t4 - t3)
"""


def compile_times() -> list[tuple[str, list[float]]]:
    """Import, first k-NN, entropy and radius calls (s) in fresh processes: no cache, then cached."""
    out = []
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for label in ("without cache (empty NUMBA_CACHE_DIR)", "with the cache written by the run above"):
            r = subprocess.run([sys.executable, "-c", FIRST_CALL], env=env, capture_output=True, text=True, check=True)
            out.append((label, [float(x) for x in r.stdout.split()]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=float, default=1e6)
    ap.add_argument("--k", type=int, default=20)
    a = ap.parse_args(argv)
    n, k = int(a.n), a.k
    P = surface(n)
    lab = KMeans(max(1, n // 400), tol=REFINE_LABEL_TOL).fit(P).labels_
    o = np.lexsort((np.arange(n), lab))
    X = with_cluster_coordinate(P[o], lab[o])  # the tree scoring builds
    cores = os.cpu_count() or 1
    load0 = os.getloadavg()[0]
    rows = []
    t, (d0, _) = best(lambda: cKDTree(X, leafsize=32, balanced_tree=False, compact_nodes=False).query(X, k=k + 2, workers=cores))
    rows.append(("scipy cKDTree (leafsize 32, workers = cores)", t, 0.0))
    try:
        import open3d as o3d

        def o3d_query():
            nn = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor(X))
            nn.knn_index()
            return nn.knn_search(o3d.core.Tensor(X), k + 2)

        t, (_, d2) = best(o3d_query)
        rows.append(("Open3D core.nns.NearestNeighborSearch", t, float(np.abs(np.sqrt(d2.numpy()) - d0).max())))
    except ImportError:
        pass
    try:
        from pykdtree.kdtree import KDTree

        t, (d1, _) = best(lambda: KDTree(X, leafsize=16).query(X, k=k + 2))
        rows.append((f"pykdtree (OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')})", t, float(np.abs(d1 - d0).max())))
    except ImportError:
        rows.append(("pykdtree", float("nan"), float("nan")))
    G = np.ascontiguousarray(P[o])
    indptr = np.r_[0, np.cumsum(np.bincount(lab[o]))]
    knn_in_clusters(G[:1000], [0, 1000], k + 1)  # compiled (or loaded from numba's cache) before the timing
    for th in (cores, 1):
        t, (d3, _) = best(lambda: knn_in_clusters(G, indptr, k + 1, threads=th))
        assert np.array_equal(d3, d0[:, 1:]), "the kernel's distances differ from cKDTree's"
        rows.append((f"cloudsieve numba kernel, threads = {th} (bit-identical to cKDTree)", t, float(np.abs(d3 - d0[:, 1:]).max())))
    print(f"{n:,} points, k = {k} (+2), {cores} cores, load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after the timings\n")
    print("| library | build + query (s) | points/s | max distance difference to cKDTree |")
    print("|---|---:|---:|---:|")
    for name, t, diff in rows:
        if np.isnan(t):
            print(f"| {name} | not installed | | |")
        else:
            print(f"| {name} | {t:.2f} | {n / t:,.0f} | {diff:.3g} |")
    print()
    print("| numba kernels, first call in a fresh process | import (s) | first k-NN call (s) | first entropy call (s) | first radius call (s) |")
    print("|---|---:|---:|---:|---:|")
    for label, ts in compile_times():
        print(f"| {label} | " + " | ".join(f"{x:.2f}" for x in ts) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
