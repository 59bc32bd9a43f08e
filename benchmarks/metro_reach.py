"""Where Metro's distance comes from (the Metro goals of the eliminate rule).

Run: ``.venv/bin/python benchmarks/metro_reach.py [--ratios 0.5,0.2,0.1] [--scans a.ply,b.laz]``

Meshes and Metro are those of ``cloudsieve evaluate`` (:mod:`cloudsieve.evaluate.mesh`: ball pivoting at r
and 2r, face sampling, 10 x faces samples, each Metro call in a forked child so that the same meshes give the
same figures). Figures are % of the bounding-box diagonal.

**Holes** (every scan of ../shared/data with at least 10,000 points). The original's mesh and its border
edges per face (:func:`cloudsieve.evaluate.mesh.border_edges`). For ``eliminate`` and the three baselines
(voxel-nearest, Poisson disk, farthest point) at each ratio: the Metro mean (the larger of the two
directions), and of the backward direction (samples on the simplified mesh, distance to the original's): the
share of samples within two point spacings of the original mesh's border, and their share of its mean.

Its part 2, "the evaluator in the loop" (docs/benchmarks.md), eliminated around fixed points with
``eliminate(fixed=)``, an option removed from src (no caller there); it runs at commit 1850bb2.

No timing here is a speed claim (load average printed).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from cloudsieve.core.eliminate import eliminate
from cloudsieve.engine.calls import forked
from cloudsieve.evaluate.baselines import fps_subset, poisson_subset, voxel_subset
from cloudsieve.evaluate.mesh import ball_pivoting, border_edges, metro, point_spacing
from cloudsieve.io import read_cloud

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SCANS = ["bun_zipper.ply", "maxplanck.ply", "autzen_trim.laz", "Megaplot.laz", "append-bug.laz",
         "vegetation_1_3.las", "pumpAVisualReferenceImage.e57"]
BASELINES = {"voxel": voxel_subset, "poisson": poisson_subset, "fps": fps_subset}
NEAR = 2.0  # "near the border": within this many point spacings of the original's


def _samples(mesh_s, mesh_t, n: int, maxdist: float) -> tuple[np.ndarray, np.ndarray]:
    """Metro's samples on *mesh_s* and their distances to *mesh_t* (run in a forked child: the same samples as
    :func:`metro`'s backward direction)."""
    import pymeshlab as pml

    ms = pml.MeshSet()
    ms.add_mesh(pml.Mesh(*mesh_s))
    ms.add_mesh(pml.Mesh(*mesh_t))
    ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, samplevert=False, sampleedge=False, sampleface=True,
                              samplenum=int(n), maxdist=pml.PureValue(maxdist), savesample=True)
    return ms.mesh(2).vertex_matrix().copy(), np.abs(ms.mesh(2).vertex_scalar_array()).astype(np.float64)


class Original:
    """One scan: its points, mesh, spacing, and the points along its mesh's border."""

    def __init__(self, path: Path):
        self.P = read_cloud(str(path))[0]
        self.diag = float(np.linalg.norm(self.P.max(0) - self.P.min(0)))
        self.mesh = forked([(ball_pivoting, self.P)])[0]
        self.spacing = point_spacing(self.P)
        b = border_edges(self.mesh[1])
        v = self.mesh[0]
        pts = np.concatenate([v[b[:, 0]] * (1 - t) + v[b[:, 1]] * t for t in (0.0, 0.25, 0.5, 0.75)])
        self.border = cKDTree(pts if len(pts) else np.full((1, 3), np.inf))
        self.per_face = len(b) / max(len(self.mesh[1]), 1)

    def figures(self, keep: np.ndarray) -> dict:
        """Point RMS, Metro both ways, and the backward samples (positions, distances, near the border)."""
        d, _ = cKDTree(self.P[keep]).query(self.P, workers=-1)
        m = forked([(ball_pivoting, self.P[keep])])[0]
        allv = np.concatenate([self.mesh[0], m[0]])
        maxdist = 10.0 * float(np.linalg.norm(allv.max(0) - allv.min(0))) + 1e-12
        n = min(max(10 * len(m[1]), 1000), 500_000)
        fig = metro(self.mesh, m)  # the evaluation's figures, to the last digit; the samples (float32 distances)
        # come from one more backward run: the same samples, as each run starts from the same forked state
        S, dist = forked([(_samples, m, self.mesh, n, maxdist)])[0]
        near = self.border.query(S, workers=-1)[0] < NEAR * self.spacing
        s = 100.0 / self.diag
        fwd, bwd = fig["forward"]["mean"] * s, fig["backward"]["mean"] * s
        return {"rms": float(np.sqrt((d ** 2).mean())) * s, "metro": max(fwd, bwd), "fwd": fwd, "bwd": bwd,
                "S": S, "dist": dist, "near": near, "near_share": float(near.mean()),
                "near_mass": float(dist[near].sum() / max(dist.sum(), 1e-300))}


def _mask(n: int, idx: np.ndarray) -> np.ndarray:
    k = np.zeros(n, dtype=bool)
    k[idx] = True
    return k


def holes(scans: list[str], ratios: list[float]) -> None:
    print("## Holes of the original's mesh and Metro's backward direction\n")
    print("| scan | border edges per face | kept | sampling | Metro mean % | backward samples near the border | "
          "their share of the backward mean |")
    print("|---|---:|---:|---|---:|---:|---:|")
    for name in scans:
        o = Original(DATA / name)
        for ratio in ratios:
            count = int(round(ratio * len(o.P)))
            for label, idx in [("eliminate", eliminate(o.P, count))] + [(b, f(o.P, count)) for b, f in BASELINES.items()]:
                f = o.figures(_mask(len(o.P), idx))
                print(f"| {name} | {o.per_face:.3f} | {ratio:.0%} | {label} | {f['metro']:.5f} | {f['near_share']:.1%} | "
                      f"{f['near_mass']:.1%} |", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ratios", default="0.5,0.2,0.1")
    ap.add_argument("--scans", default=",".join(SCANS))
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    warnings.filterwarnings("ignore")
    ratios = [float(r) for r in args.ratios.split(",")]
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n")
    t0 = time.perf_counter()
    holes(args.scans.split(","), ratios)
    print(f"\n{time.perf_counter() - t0:.0f} s; load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
