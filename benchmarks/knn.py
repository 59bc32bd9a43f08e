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
scoring stage's throughput.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from core import surface  # noqa: E402

from cloudsieve.core import KMeans  # noqa: E402
from cloudsieve.core.knn import with_cluster_coordinate  # noqa: E402
from cloudsieve.core.refine import REFINE_LABEL_TOL  # noqa: E402


def best(fn, reps=3):
    out, ts = None, []
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return min(ts), out


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
    print(f"{n:,} points, k = {k} (+2), {cores} cores, load average {os.getloadavg()[0]:.1f}\n")
    print("| library | build + query (s) | points/s | max distance difference to cKDTree |")
    print("|---|---:|---:|---:|")
    for name, t, diff in rows:
        if np.isnan(t):
            print(f"| {name} | not installed | | |")
        else:
            print(f"| {name} | {t:.2f} | {n / t:,.0f} | {diff:.3g} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
