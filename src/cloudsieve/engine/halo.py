"""Halos: the points of neighbouring cells near a cell's border (density context, never pruned).

A point z of cell j is in the halo of cell i when its distance to the
bisector plane of c_i and c_j, ``s_ij(z) = (z - (c_i + c_j) / 2) . (c_j - c_i)
/ |c_j - c_i|``, is at most ``margin``: a superset of the points within
``margin`` of i's Voronoi region. :func:`read_halo` tests the source cells'
runs; a rule that reads every cell first (``eliminate``) stores each cell's
**band** (:func:`band_mask`), and :func:`read_band_halo` gives the same points.
"""

from __future__ import annotations

import numpy as np

from ..store.streaming import gathered
from .runs import decode_rows

__all__ = ["halo_distance", "halo_mask", "read_halo", "band_mask", "read_band_halo", "band_halo"]


def halo_distance(z: np.ndarray, ci: np.ndarray, cj: np.ndarray) -> np.ndarray:
    """Signed distance (n,) of points z (n, 3) of cell j to the bisector of c_i and c_j, positive on c_j's side."""
    mid, diff, norm = _bisector(ci, cj)
    return ((z - mid) * diff).sum(axis=-1) / norm


def _bisector(ci, cj):
    """Midpoint, normal c_j - c_i and its length of the bisector plane(s) of c_i and c_j (broadcast)."""
    diff = cj - ci
    return (ci + cj) * 0.5, diff, np.sqrt((diff * diff).sum(axis=-1))


def halo_mask(z: np.ndarray, centers: np.ndarray, cell: int, source: int, margin: float) -> np.ndarray:
    """Which points z of cell *source* belong to the halo of *cell*: (n,) bool."""
    return halo_distance(z, centers[cell], centers[source]) <= margin


def read_halo(group, part_runs: dict[int, np.ndarray], centers: np.ndarray, cell: int, margin: float,
              return_index: bool = False):
    """Halo of *cell*: points (h, 3) float64 of its source cells within *margin* of its region.

    *part_runs*: each source cell's runs ``(chunk, start, stop[, first])``
    (:func:`cloudsieve.engine.runs.cell_runs`; ``first`` needed for
    *return_index*); *centers*: (P, 3) or int -> (3,). Points come by source
    cell, increasing, each in input order. *return_index* also returns each
    point's cell and position in that cell, (h,) int64 each.
    """
    arr = group["partition/xyz"].async_array
    out, cells, pos = [], [], []
    for src in sorted(part_runs):
        runs = [run for run in part_runs[src] if int(run[2]) > int(run[1])]
        # one source's runs read concurrently
        got = gathered(arr.getitem((int(run[0]), slice(int(run[1]), int(run[2])))) for run in runs)
        for run, raw in zip(runs, got):
            z = decode_rows(group, np.asarray(raw))
            m = halo_mask(z, centers, cell, src, margin)
            if m.any():
                out.append(z[m])
                if return_index:
                    sel = np.flatnonzero(m)
                    cells.append(np.full(len(sel), src, dtype=np.int64))
                    pos.append(int(run[3]) + sel)
    pts = np.concatenate(out, axis=0) if out else np.empty((0, 3))
    if not return_index:
        return pts
    if not out:
        return pts, np.empty(0, np.int64), np.empty(0, np.int64)
    return pts, np.concatenate(cells), np.concatenate(pos).astype(np.int64)


def band_mask(z: np.ndarray, centers: dict, source: int, dependents, margin: float) -> np.ndarray:
    """Which points z (n, 3) of cell *source* lie in the halo of a cell of *dependents* (its band): (n,) bool.

    *centers*: int -> centre of *source* and every dependent.
    """
    from ..core.kernels.bisector import within_any

    deps = [int(i) for i in dependents]
    if not deps or not len(z):
        return np.zeros(len(z), dtype=bool)
    mid, diff, norm = _bisector(np.array([centers[i] for i in deps], dtype=np.float64),
                                np.asarray(centers[source], dtype=np.float64))  # halo_distance's planes
    return within_any(np.ascontiguousarray(z, dtype=np.float64), mid, diff, norm, float(margin))


def read_band_halo(group, sources: dict[int, int], centers, cell: int, margin: float, prefix: str = "simplify/band"):
    """:func:`read_halo` (with ``return_index``) from the stored bands of the halo sources.

    *group* holds ``{prefix}_xyz`` (R, 3) and ``{prefix}_pos`` (R,), a cell's
    band at the start of its region, and ``{prefix}_count`` (P,); *sources*
    maps each source cell to its region's start.
    """
    xyz, pos, cnt = (group[f"{prefix}_{n}"].async_array for n in ("xyz", "pos", "count"))
    srcs = sorted(sources)
        # two event-loop calls (counts, then bands), not three per source
    counts = [int(np.asarray(c)[0]) for c in gathered(cnt.getitem(slice(s, s + 1)) for s in srcs)]
    spans = [(s, int(sources[s]), int(sources[s]) + c) for s, c in zip(srcs, counts) if c > 0]
    got = gathered(arr.getitem(slice(a, b)) for _, a, b in spans for arr in (xyz, pos))
    return band_halo(((src, np.asarray(z), np.asarray(p)) for (src, _, _), z, p in zip(spans, got[0::2], got[1::2])),
                     centers, cell, margin)


def band_halo(bands, centers, cell: int, margin: float):
    """:func:`read_band_halo` from bands in hand: (source, points (b, 3), positions (b,)), sources increasing."""
    out, cells, where = [], [], []
    for src, z, p in bands:
        m = halo_mask(z, centers, cell, src, margin)
        if m.any():
            out.append(z[m])
            cells.append(np.full(int(m.sum()), src, dtype=np.int64))
            where.append(p[m].astype(np.int64))
    if not out:
        return np.empty((0, 3)), np.empty(0, np.int64), np.empty(0, np.int64)
    return np.concatenate(out, axis=0), np.concatenate(cells), np.concatenate(where)
