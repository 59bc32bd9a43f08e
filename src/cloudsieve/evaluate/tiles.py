"""The surface level's tiles: where they are, which points they hold, and the spread of their figures.

**fixed** (:func:`choose_tiles`): T tiles on k-means centres of a uniform sample, M points each; **budget**
(``cloudsieve evaluate``'s default): T tiles (8) on random points, sized to take the budget at
:data:`SURFACE_RATE` (:func:`budget_tile_points`), with standard errors (:func:`spread`); **full**
(:func:`partition_tiles`): every point, in cells of about M. One streamed pass gathers them, after one for
:func:`uniform_sample`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["SAMPLE_SIZE", "MIN_TILE_POINTS", "BUDGET_TILES", "SURFACE_RATE", "sample_indices", "sample_rows",
           "uniform_sample", "choose_tiles", "random_tiles", "gather_tiles", "partition_tiles", "cell_points",
           "budget_tile_points", "spread"]

#: points of the uniform sample the tiles are drawn from 
SAMPLE_SIZE = 200_000
#: the smallest tile a budget makes (smaller tiles mesh too little surface to compare)
MIN_TILE_POINTS = 10_000
#: original points a second of the surface level on 2 cores (docs/benchmarks.md, "Evaluation"); a budget sizes
#: its tiles at this rate, never by a clock, so tiles and figures do not depend on the machine or its load
SURFACE_RATE = 4_000
#: tiles a budget is sized for (at least): enough for a standard error over tiles
BUDGET_TILES = 8


def sample_indices(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices (int64) of a uniform sample of *size* of *n* points drawn with *rng* (all of them when
    size >= n)."""
    if size >= n:
        return np.arange(n, dtype=np.int64)
    return np.sort(rng.choice(n, size=size, replace=False)).astype(np.int64)


def sample_rows(src, idx: np.ndarray) -> np.ndarray:
    """The coordinates (len(idx), 3) of the sorted global rows *idx* of *src*, in one streamed pass."""
    parts = []
    for chunk in src.chunks():
        a, b = np.searchsorted(idx, [chunk.start, chunk.stop])
        parts.append(chunk.xyz[idx[a:b] - chunk.start])
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def uniform_sample(src, size: int = SAMPLE_SIZE, seed: int = 0) -> tuple[np.ndarray, int]:
    """(a uniform seeded sample of at most *size* points of *src* (one streamed pass), the cloud's count)."""
    n = src.count_points()
    return sample_rows(src, sample_indices(n, size, np.random.default_rng(seed))), int(n)


def _radii(tree: cKDTree, centres: np.ndarray, tile_points: int, n: int, margin: float = 1.0) -> np.ndarray:
    k = max(8, min(tree.n, int(round(tile_points * tree.n / n))))
    d, _ = tree.query(centres, k=k)
    return margin * (d[:, -1] if d.ndim == 2 else d)


def choose_tiles(source: Any, tiles: int, tile_points: int, *, seed: int = 0, sample_size: int = 200_000) -> list[dict]:
    """Pick *tiles* tile centres spread over the cloud and a first radius each: ``[{"centre", "radius"}]``.
    Centres are seeded k-means centres of a uniform sample, snapped to a sample point; radii hold about
    *tile_points* points. Empty when the cloud has at most *tile_points* points (one tile, the whole cloud)."""
    from scipy.cluster.vq import kmeans2

    from ._source import open_source

    src = open_source(source)
    n = src.count_points()
    if n <= tile_points:
        return []
    rng = np.random.default_rng(seed)
    sample = sample_rows(src, np.sort(rng.choice(n, size=min(n, sample_size), replace=False)))  # rng goes on below
    tiles = int(min(tiles, max(1, n // tile_points)))
    centres, _ = kmeans2(sample, tiles, seed=rng, minit="++")
    tree = cKDTree(sample)
    _, nearest = tree.query(centres)
    centres = sample[nearest]
    radii = _radii(tree, centres, tile_points, n)
    return [{"centre": c.tolist(), "radius": float(r)} for c, r in zip(centres, radii)]


def random_tiles(sample: np.ndarray, n: int, count: int, tile_points: int, *, seed: int = 0) -> list[dict]:
    """*count* tiles centred on random points of *sample*, radii holding about 1.3 x *tile_points* points."""
    rng = np.random.default_rng([seed, 7])
    centres = sample[rng.choice(len(sample), size=min(count, len(sample)), replace=False)]
    radii = _radii(cKDTree(sample), centres, tile_points, n, margin=1.3)
    return [{"centre": c.tolist(), "radius": float(r)} for c, r in zip(centres, radii)]


def gather_tiles(src, tiles: list[dict], tile_points: int) -> list[np.ndarray]:
    """Stream the original, keeping per tile the points within its radius (at most the *tile_points* nearest).
    Sets each tile's ``radius`` to the one it ends with."""
    centres = np.array([t["centre"] for t in tiles], dtype=np.float64).reshape(-1, 3)
    radii = np.array([t["radius"] for t in tiles], dtype=np.float64)
    kept: list[list[np.ndarray]] = [[] for _ in tiles]
    dist: list[list[np.ndarray]] = [[] for _ in tiles]
    counts = np.zeros(len(tiles), np.int64)
    for chunk in src.chunks():
        xyz = chunk.xyz
        if len(xyz) == 0:
            continue
        order = np.argsort(xyz[:, 0], kind="stable")
        xs = xyz[order, 0]
        for i, c in enumerate(centres):
            a, b = np.searchsorted(xs, [c[0] - radii[i], c[0] + radii[i]], side="left")
            if b <= a:
                continue
            rows = np.sort(order[a:b])
            d = np.sqrt(((xyz[rows] - c) ** 2).sum(axis=1))
            w = d <= radii[i]
            if w.any():
                kept[i].append(xyz[rows[w]])
                dist[i].append(d[w])
                counts[i] += int(w.sum())
            if counts[i] > tile_points:  # keep the M nearest, shrink the radius
                p, q = np.concatenate(kept[i]), np.concatenate(dist[i])
                o = np.argsort(q, kind="stable")[:tile_points]
                radii[i] = q[o[-1]]
                o = np.flatnonzero(q <= radii[i])
                kept[i], dist[i], counts[i] = [p[o]], [q[o]], len(o)
    out = []
    for i, t in enumerate(tiles):
        t["radius"] = float(radii[i])
        out.append(np.concatenate(kept[i]) if kept[i] else np.zeros((0, 3)))
    return out


def partition_tiles(src, sample: np.ndarray, n: int, tile_points: int, *,
                    seed: int = 0) -> tuple[list[dict], list[np.ndarray], np.ndarray]:
    """Every point in one tile: the cells of ceil(n / M) k-means centres of *sample* (one streamed pass).
    Returns (tiles, original points per tile, every centre); a tile has ``centre``, ``cell`` (the centre's index)
    and ``radius`` (its farthest point). Empty cells make no tile."""
    from scipy.cluster.vq import kmeans2

    count = max(1, -(-n // tile_points))
    centres, _ = kmeans2(sample, count, seed=np.random.default_rng(seed), minit="++")
    tree = cKDTree(centres)
    parts: list[list[np.ndarray]] = [[] for _ in range(count)]
    for chunk in src.chunks():
        if len(chunk.xyz):
            _, lab = tree.query(chunk.xyz, workers=-1)
            o = np.argsort(lab, kind="stable")
            bounds = np.searchsorted(lab[o], np.arange(count + 1))
            for i in np.flatnonzero(np.diff(bounds)):
                parts[i].append(chunk.xyz[o[bounds[i]:bounds[i + 1]]])
    tiles, origs = [], []
    for i in range(count):
        if not parts[i]:
            continue
        pts = np.concatenate(parts[i])
        r = float(np.sqrt(((pts - centres[i]) ** 2).sum(axis=1)).max())
        tiles.append({"centre": centres[i].tolist(), "radius": r, "cell": i})
        origs.append(pts)
    return tiles, origs, centres


def cell_points(xyz: np.ndarray, centres: np.ndarray, tiles: list[dict]) -> list[np.ndarray]:
    """The points of *xyz* (in memory) in each of *tiles* of :func:`partition_tiles`: those nearest its centre."""
    _, lab = cKDTree(centres).query(xyz, workers=-1)
    return [xyz[np.flatnonzero(lab == t["cell"])] for t in tiles]


def budget_tile_points(rate: float, remaining: float, tiles: int, tile_points: int) -> int:
    """Tile size for *tiles* tiles to take *remaining* seconds at *rate* points/s, within [MIN_TILE_POINTS,
    *tile_points*]."""
    low = min(MIN_TILE_POINTS, tile_points)
    return int(min(tile_points, max(low, rate * max(remaining, 0.0) / max(tiles, 1))))


def _weighted_se(x: np.ndarray, w: np.ndarray) -> float:
    """Standard error of the weighted mean sum(w x) / sum(w) over T sampled tiles (ratio estimator)."""
    t = len(x)
    if t < 2 or w.sum() <= 0:
        return math.nan
    m = float((w * x).sum() / w.sum())
    return float(math.sqrt(t / (t - 1) * ((w * (x - m)) ** 2).sum()) / w.sum())


def spread(recs: list[dict], diagonal: float) -> dict:
    """Standard errors over sampled tiles of the aggregated figures (% of *diagonal*).
    Per direction (and ``on_surface``): ``mean_pct_se`` and ``rms_pct_se``, tiles taken as a random sample (NaN
    below 2 tiles); ``compact_share_se``."""
    scale = 100.0 / diagonal if diagonal > 0 else math.nan
    out: dict[str, Any] = {"tiles": len(recs)}
    for name, get in (("forward", lambda r: r.get("forward")), ("backward", lambda r: r.get("backward")),
                      ("on_surface", lambda r: (r.get("backward") or {}).get("on_surface"))):
        rs = [d for d in map(get, recs) if d and d.get("samples")]
        if not rs:
            continue
        w = np.array([d["samples"] for d in rs], dtype=np.float64)
        mean = np.array([d["mean"] for d in rs])
        ms = np.square([d["rms"] for d in rs])
        rms = math.sqrt(float((w * ms).sum() / w.sum()))
        se_ms = _weighted_se(ms, w)
        out[name] = {"mean_pct_se": _weighted_se(mean, w) * scale,
                     "rms_pct_se": (se_ms / (2 * rms) if rms > 0 else math.nan) * scale}
    faces = np.array([r["simplified"].get("faces", 0) for r in recs if "simplified" in r], dtype=np.float64)
    share = np.nan_to_num([r["simplified"].get("compact_share", 0.0) for r in recs if "simplified" in r])
    out["compact_share_se"] = _weighted_se(share, faces) if len(faces) else math.nan
    return out
