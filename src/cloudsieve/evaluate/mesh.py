"""Meshes and their figures: ball pivoting, Metro distances, triangle compactness.

Ball pivoting (pymeshlab; radius r then 2r, r = :func:`point_spacing`) meshes a cloud. :func:`metro` compares two
meshes both ways (pymeshlab's ``get_hausdorff_distance``, face sampling, MaxDist ten diagonals so no sample is
dropped) in forked children (:func:`cloudsieve.engine.calls.forked`): pymeshlab's random generator is
process-wide and never reseeded, so the same meshes give the same figures. Compactness c = 4*sqrt(3)*area /
(l1^2 + l2^2 + l3^2): 1 equilateral, 0 degenerate; a mesh is "compact" when at least 50% of its triangles have
c >= 0.6 (the paper's criterion). Border edges measure a mesh's holes, which Metro measures more than the
sampling (docs/benchmarks.md, "Where Metro's distance comes from").
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..engine.calls import forked
from ..errors import MissingDependencyError

__all__ = [
    "COMPACT_THRESHOLD",
    "COMPACT_SHARE",
    "compactness",
    "compactness_summary",
    "border_edges",
    "point_spacing",
    "ball_pivoting",
    "metro",
    "on_border",
    "load_mesh",
    "crop_mesh",
]

COMPACT_THRESHOLD = 0.6
COMPACT_SHARE = 0.5
HIST_BINS = 50


def compactness(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Compactness (f,) in [0, 1] of every triangle of *faces* (f, 3) over *vertices* (v, 3).

    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    >>> round(float(compactness(v, np.array([[0, 1, 2]]))[0]), 6)  # sqrt(3)/2
    0.866025
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.zeros(0)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    ab, bc, ca = b - a, c - b, a - c
    area = 0.5 * np.linalg.norm(np.cross(ab, -ca), axis=1)
    s = (ab * ab).sum(1) + (bc * bc).sum(1) + (ca * ca).sum(1)
    out = np.zeros(len(f))
    ok = s > 0
    out[ok] = 4.0 * math.sqrt(3.0) * area[ok] / s[ok]
    return np.clip(out, 0.0, 1.0)


def compactness_summary(c: np.ndarray) -> dict:
    """Share of triangles with c >= 0.6, mean, the "compact" verdict, and a histogram (50 bins on [0, 1])."""
    n = int(len(c))
    good = int((c >= COMPACT_THRESHOLD).sum())
    share = good / n if n else float("nan")
    return {
        "faces": n,
        "compact_count": good,
        "compact_share": share,
        "compact": bool(n and share >= COMPACT_SHARE),
        "compactness_mean": float(c.mean()) if n else float("nan"),
        "compactness_hist": np.histogram(c, bins=HIST_BINS, range=(0.0, 1.0))[0].tolist(),
    }


def border_edges(faces: np.ndarray) -> np.ndarray:
    """Edges (e, 2) of exactly one triangle of *faces* (f, 3), lower index first, sorted: holes and rim.

    >>> border_edges(np.array([[0, 1, 2], [2, 1, 3]])).tolist()  # two triangles sharing edge 1-2
    [[0, 1], [0, 2], [1, 3], [2, 3]]
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    if len(e) == 0:
        return np.zeros((0, 2), np.int64)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 1]


def point_spacing(points: np.ndarray, k: int = 6) -> float:
    """Median over points of the mean distance to their *k* nearest neighbours."""
    n = len(points)
    if n < 2:
        return 0.0
    k = min(k, n - 1)
    d, _ = cKDTree(points).query(points, k=k + 1, workers=-1)
    return float(np.median(d[:, 1:].mean(axis=1)))


def _pymeshlab():
    try:
        import pymeshlab
    except ImportError as exc:  # pragma: no cover
        raise MissingDependencyError("surface evaluation needs pymeshlab: pip install pymeshlab") from exc
    return pymeshlab


def ball_pivoting(points: np.ndarray, *, radius: float | None = None, k_normals: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Mesh *points* (n, 3) by ball pivoting (pymeshlab), radius r then 2r (default :func:`point_spacing`).
    Returns ``(vertices (v, 3) float64, faces (f, 3) int32)``."""
    pml = _pymeshlab()
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) < 3:
        return points, np.zeros((0, 3), np.int32)
    r = point_spacing(points) if radius is None else float(radius)
    ms = pml.MeshSet()
    ms.add_mesh(pml.Mesh(points))
    ms.compute_normal_for_point_clouds(k=int(min(k_normals, len(points) - 1)))
    if r > 0:
        for mult in (1.0, 2.0):
            ms.generate_surface_reconstruction_ball_pivoting(ballradius=pml.PureValue(mult * r))
    m = ms.current_mesh()
    return m.vertex_matrix().copy(), m.face_matrix().astype(np.int32)


def load_mesh(path: str) -> tuple[np.ndarray, np.ndarray]:
    """A triangle mesh from a file pymeshlab reads: ``(vertices (v, 3), faces (f, 3))``.
    Raises InputNotFoundError (no file) or InputFormatError (unreadable, or no triangle)."""
    import os

    from ..errors import InputFormatError, InputNotFoundError

    if not os.path.isfile(path):
        raise InputNotFoundError(f"reference mesh not found: {path}")
    pml = _pymeshlab()
    ms = pml.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except pml.PyMeshLabException as exc:
        raise InputFormatError(f"cannot read the reference mesh {path}: {exc}") from None
    m = ms.current_mesh()
    if m.face_number() == 0:
        raise InputFormatError(f"the reference mesh {path} has no triangle ({m.vertex_number()} vertices)")
    return m.vertex_matrix().copy(), m.face_matrix().astype(np.int32)


def crop_mesh(mesh: tuple[np.ndarray, np.ndarray], centre, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The faces of *mesh* whose three vertices lie within *radius* of *centre* (vertices renumbered)."""
    v, f = mesh
    inside = np.linalg.norm(v - np.asarray(centre, dtype=np.float64), axis=1) <= radius
    f = f[inside[f].all(axis=1)]
    used = np.unique(f)
    new = np.full(len(v), -1, np.int64)
    new[used] = np.arange(len(used))
    return v[used], new[f].astype(np.int32)


def _metro_one(ms, sampled: int, target: int, samples: int, maxdist: float, save: bool = False) -> dict:
    pml = _pymeshlab()
    r = ms.get_hausdorff_distance(sampledmesh=sampled, targetmesh=target, samplevert=False, sampleedge=False,
                                  sampleface=True, samplenum=int(samples), maxdist=pml.PureValue(maxdist),
                                  savesample=save)
    return {"mean": float(r["mean"]), "rms": float(r["RMS"]), "max": float(r["max"]),
            "min": float(r["min"]), "samples": int(r["n_samples"])}


def on_border(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, tol: float) -> np.ndarray:
    """Which *points* (p, 3) lie within *tol* of a border edge of the mesh: bool (p,).
    Candidates are the 8 border edges with the nearest midpoints."""
    edges = border_edges(faces)
    out = np.zeros(len(points), bool)
    if len(edges) == 0 or len(points) == 0:
        return out
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    k = min(8, len(edges))
    _, cand = cKDTree(0.5 * (a + b)).query(points, k=k, workers=-1)
    cand = cand.reshape(len(points), k)
    ab = (b - a)[cand]
    ap = points[:, None, :] - a[cand]
    t = np.clip(np.einsum("pki,pki->pk", ap, ab) / np.maximum(np.einsum("pki,pki->pk", ab, ab), 1e-300), 0, 1)
    d = np.linalg.norm(ap - t[..., None] * ab, axis=2).min(axis=1)
    return d <= tol


def _metro_dir(mesh_s, mesh_t, n: int, maxdist: float, holes: bool = False) -> dict:
    """One Metro direction: samples on *mesh_s*, distances to *mesh_t*.
    *holes* adds ``on_surface``: the figures over samples whose closest point is not on *mesh_t*'s border (within
    1e-3 median edge), and ``excluded``."""
    pml = _pymeshlab()
    ms = pml.MeshSet()
    ms.add_mesh(pml.Mesh(mesh_s[0], mesh_s[1]))
    ms.add_mesh(pml.Mesh(mesh_t[0], mesh_t[1]))
    rec = _metro_one(ms, 0, 1, n, maxdist, save=holes)
    if holes:
        closest, sample = ms.mesh(2).vertex_matrix(), ms.mesh(3).vertex_matrix()  # as vcg adds them
        v, f = mesh_t
        edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1))) if len(f) else 0.0
        out = on_border(closest, v, f, 1e-3 * edge)
        d = np.linalg.norm(sample - closest, axis=1)[~out]
        rec["on_surface"] = {"mean": float(d.mean()) if len(d) else math.nan,
                             "rms": float(np.sqrt(np.mean(d * d))) if len(d) else math.nan,
                             "max": float(d.max()) if len(d) else math.nan, "samples": int(len(d)),
                             "excluded": int(out.sum())}
    return rec


def metro(mesh_a: tuple[np.ndarray, np.ndarray], mesh_b: tuple[np.ndarray, np.ndarray], *,
          samples: int | None = None, max_samples: int = 500_000) -> dict:
    """Metro distances between two meshes, both ways (pymeshlab, face sampling), each in a forked child.
    *samples* per direction defaults to 10 x the sampled mesh's faces, at most *max_samples*. Returns ``forward``
    (samples on a, distances to b) and ``backward``, each ``mean, rms, max, min, samples``;
    ``backward["on_surface"]`` as :func:`_metro_dir`'s *holes*. The figures equal a direct
    ``get_hausdorff_distance`` call made first in a fresh process."""
    a = (np.ascontiguousarray(mesh_a[0], dtype=np.float64), np.ascontiguousarray(mesh_a[1], dtype=np.int32))
    b = (np.ascontiguousarray(mesh_b[0], dtype=np.float64), np.ascontiguousarray(mesh_b[1], dtype=np.int32))
    allv = np.concatenate([a[0], b[0]])
    maxdist = 10.0 * float(np.linalg.norm(allv.max(0) - allv.min(0))) + 1e-12

    def n_of(mesh):
        return samples if samples is not None else min(max(10 * len(mesh[1]), 1000), max_samples)

    fwd, bwd = forked([(_metro_dir, a, b, n_of(a), maxdist), (_metro_dir, b, a, n_of(b), maxdist, True)])
    return {"forward": fwd, "backward": bwd}
