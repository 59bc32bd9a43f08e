"""The coarse levels of a ranked cloud's COPC: lowest rank per voxel against the first point per voxel.

    .venv/bin/python benchmarks/copc_rank.py                          # autzen_trim.laz, leaves of 50,000 and 5,000
    .venv/bin/python benchmarks/copc_rank.py --leaf 20000 scan.laz

For each scan: ``simplify SCAN lod.laz --ratio 0.5,0.2,0.1 --rank`` (in a
temporary folder), its first output ingested and written as COPC twice per
leaf size (``export_copc`` with ``rank=True``: each voxel keeps its lowest
rank; ``rank=False``: its first point, as PDAL and Untwine). For the points
of the levels 0..L (L = 0, 1, 2: what a viewer draws at coarse zoom), the
forward point RMS (every original point to its nearest shown point, % of the
bounding-box diagonal) and D1 PSNR (forward, peak = the diagonal), and the
same for the first N ranks (N = the points shown by the ranked file): the
rank's own prefix at that count. One table, with the load average.
"""

from __future__ import annotations

import argparse
import math
import os
import struct
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np
from scipy.spatial import cKDTree

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def node_depths(path: str) -> tuple[np.ndarray, np.ndarray]:
    """The points (n, 3) of a COPC file, in file order, and the depth (n,) of the node holding each."""
    with open(path, "rb") as f:
        f.seek(375 + 54 + 40)  # the info VLR: the root hierarchy page's offset and size
        offset, size = struct.unpack("<2Q", f.read(16))
        f.seek(offset)
        table = np.frombuffer(f.read(size), dtype=[("d", "<i4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4"),
                                                   ("offset", "<u8"), ("nbytes", "<i4"), ("count", "<i4")])
    table = table[np.argsort(table["offset"])]
    cloud = laspy.read(path)
    depth = np.repeat(table["d"].astype(np.int64), table["count"].astype(np.int64))
    return np.column_stack([cloud.x, cloud.y, cloud.z]), depth


def forward(tree: cKDTree, shown: np.ndarray, diagonal: float) -> tuple[float, float]:
    """RMS (% of *diagonal*) and D1 PSNR (dB) from the original points of *tree* to *shown*."""
    d, _ = cKDTree(shown).query(tree.data, workers=1)
    mse = float(np.mean(d * d))
    return 100.0 * math.sqrt(mse) / diagonal, 10.0 * math.log10(3.0 * diagonal * diagonal / mse)


def measure(scan: Path, leaves: list[int], folder: str) -> list[tuple]:
    import cloudsieve
    from cloudsieve.io.rank import RANK_DIM
    from cloudsieve.store import ingest
    from cloudsieve.store.copc import export_copc

    cloudsieve.simplify(str(scan), os.path.join(folder, "lod.laz"), ratio=[0.5, 0.2, 0.1], rank=True)
    first = os.path.join(folder, "lod-0.5.laz")
    lod = laspy.read(first)
    by_rank = np.column_stack([lod.x, lod.y, lod.z])[np.argsort(np.asarray(lod[RANK_DIM]))]
    original = laspy.read(str(scan))
    xyz = np.column_stack([original.x, original.y, original.z])
    diagonal = float(np.linalg.norm(xyz.max(axis=0) - xyz.min(axis=0)))
    tree = cKDTree(xyz)
    store = ingest(first, os.path.join(folder, "lod.zarr"))
    rows = []
    for leaf in leaves:
        files = {}
        for ranked in (True, False):
            files[ranked] = os.path.join(folder, f"{leaf}-{ranked}.copc.laz")
            export_copc(store, files[ranked], leaf_points=leaf, task_points=max(leaf, 1_000_000), rank=ranked)
        levels = {ranked: node_depths(path) for ranked, path in files.items()}
        for top in range(3):
            if top > levels[True][1].max():
                break
            row = [scan.name, len(xyz), len(by_rank), leaf, top]
            for ranked in (True, False):
                points, depth = levels[ranked]
                shown = points[depth <= top]
                row += [len(shown), *forward(tree, shown, diagonal)]
            row += list(forward(tree, by_rank[: row[5]], diagonal))
            rows.append(tuple(row))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, help="scans (default: autzen_trim.laz of ../shared/data)")
    parser.add_argument("--leaf", default="50000,5000", help="leaf sizes (points), comma-separated")
    args = parser.parse_args(argv)
    files = args.files or [DATA / "autzen_trim.laz"]
    leaves = [int(v) for v in args.leaf.split(",")]
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    rows = []
    for scan in files:
        with tempfile.TemporaryDirectory() as folder:
            rows += measure(scan, leaves, folder)
    load1 = os.getloadavg()
    print(f"COPC levels 0..L of lod-0.5 (simplify --ratio 0.5,0.2,0.1 --rank): forward RMS % of the diagonal and "
          f"D1 PSNR dB, original -> the shown points")
    print(f"| scan | points | lod-0.5 | leaf | levels | shown (rank) | RMS % | D1 dB | shown (first) | RMS % | D1 dB "
          f"| rank prefix RMS % | D1 dB |")
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, n, m, leaf, top, a, ra, da, b, rb, db, rp, dp in rows:
        print(f"| {name} | {n:,} | {m:,} | {leaf:,} | 0..{top} | {a:,} | {ra:.4f} | {da:.2f} | {b:,} | {rb:.4f} | "
              f"{db:.2f} | {rp:.4f} | {dp:.2f} |")
    print(f"{time.perf_counter() - t0:.1f} s; load average (1, 5, 15 min) before {load0[0]:.2f} {load0[1]:.2f} "
          f"{load0[2]:.2f}, after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
