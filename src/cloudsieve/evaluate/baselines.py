"""Baseline simplifications, each returning sorted indices of kept original points (seeded, in memory).

``random``: a uniform sample of exactly *count*; ``voxel``: the point nearest each occupied voxel's centroid, the
size bisected to within 0.5% of *count*; ``poisson``: Poisson-disk dart throwing in a seeded order (the first
maximal independent set of the r-neighbour graph, Luby rounds), r bisected likewise (pymeshlab's cannot be
seeded); ``fps``: farthest point sampling (open3d), O(n x count), refused beyond ``FPS_MAX_WORK``; ``km`` /
``fcm``: :func:`cloudsieve.core.simplify.simplify_points`.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.spatial import cKDTree

from ..core.rules import MEMORY_RULE
from ..core.rules import get as get_rule
from ..errors import CloudsieveError, InvalidParameterError
from ..params import check

logger = logging.getLogger(__name__)

__all__ = ["BASELINES", "FPS_MAX_WORK", "random_subset", "voxel_subset", "poisson_subset", "fps_subset",
           "entropy_subset", "run_method"]

FPS_MAX_WORK = 2e10


def _check(points: np.ndarray, count: int) -> tuple[np.ndarray, int]:
    points = np.ascontiguousarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InvalidParameterError(f"points must have shape (n, 3), got {points.shape}")
    return points, min(check("count", count), len(points))  # above the cloud's size: all of them, as everywhere


def random_subset(points: np.ndarray, count: int, *, seed: int = 0) -> np.ndarray:
    """Uniform seeded sample of *count* points; sorted int64 indices."""
    points, count = _check(points, count)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(len(points), size=count, replace=False)).astype(np.int64)


def _voxel_keys(points: np.ndarray, lo: np.ndarray, size: float) -> np.ndarray:
    q = np.floor((points - lo) / size).astype(np.int64)
    dims = q.max(axis=0) + 1
    if float(dims[0]) * float(dims[1]) * float(dims[2]) < 2**62:
        return q[:, 0] + dims[0] * (q[:, 1] + dims[1] * q[:, 2])
    _, inv = np.unique(q, axis=0, return_inverse=True)
    return inv.ravel().astype(np.int64)


def voxel_subset(points: np.ndarray, count: int, *, tol: float = 0.005, max_iter: int = 80) -> np.ndarray:
    """The original point nearest each voxel's centroid, voxel size bisected to give *count* voxels (within *tol*).
    Returns sorted int64 indices (one per occupied voxel)."""
    points, count = _check(points, count)
    lo = points.min(axis=0)
    span = float((points.max(axis=0) - lo).max()) or 1.0
    a, b = math.log(span * 1e-9), math.log(span * 2)  # a: ~every point alone; b: one voxel
    best = None
    for _ in range(max_iter):
        mid = 0.5 * (a + b)
        keys = _voxel_keys(points, lo, math.exp(mid))
        k = len(np.unique(keys))
        if best is None or abs(k - count) < abs(best[1] - count):
            best = (math.exp(mid), k)
        if abs(k - count) <= tol * count:
            break
        if k > count:
            a = mid
        else:
            b = mid
    size, k = best
    logger.info("voxel: size %.6g -> %d voxels (asked %d)", size, k, count)
    keys = _voxel_keys(points, lo, size)
    _, inv = np.unique(keys, return_inverse=True)
    inv = inv.ravel()
    n = np.bincount(inv).astype(np.float64)
    centroid = np.stack([np.bincount(inv, weights=points[:, j]) / n for j in range(3)], axis=1)
    dist = ((points - centroid[inv]) ** 2).sum(axis=1)
    order = np.lexsort((np.arange(len(points)), dist, inv))
    first = np.r_[0, np.flatnonzero(np.diff(inv[order])) + 1]
    return np.sort(order[first]).astype(np.int64)


def _greedy_mis(n: int, i: np.ndarray, j: np.ndarray, prio: np.ndarray) -> np.ndarray:
    """Lexicographically-first maximal independent set (lowest priority first) of the graph (i, j), both directions
    listed."""
    state = np.zeros(n, np.int8)  # 0 undecided, 1 kept, 2 dropped
    while True:
        und = state == 0
        if not und.any():
            break
        m = und[i] & und[j]
        minnb = np.full(n, np.iinfo(np.int64).max)
        np.minimum.at(minnb, i[m], prio[j[m]])
        sel = und & (prio < minnb)
        state[sel] = 1
        drop = j[sel[i] & (state[j] == 0)]
        state[drop] = 2
    return state == 1


def poisson_subset(points: np.ndarray, count: int, *, seed: int = 0, tol: float = 0.005, max_iter: int = 40) -> np.ndarray:
    """Poisson-disk subsample, radius bisected to give *count* points (within *tol*); sorted int64 indices."""
    points, count = _check(points, count)
    n = len(points)
    if count == n:
        return np.arange(n, dtype=np.int64)
    prio = np.random.default_rng(seed).permutation(n).astype(np.int64)
    tree = cKDTree(points)
    lo_b = points.min(axis=0)
    span = float(np.linalg.norm(points.max(axis=0) - lo_b)) or 1.0
    # first guess: spacing of a cloud with `count` points on a surface
    d, _ = tree.query(points[:: max(1, n // 2000)], k=2)
    s0 = float(np.median(d[:, 1])) or span * 1e-6
    a, b = math.log(s0 * 0.1), math.log(s0 * math.sqrt(n / count) * 4)
    best = None
    for _ in range(max_iter):
        r = math.exp(0.5 * (a + b))
        pairs = tree.query_pairs(r, output_type="ndarray")
        i = np.concatenate([pairs[:, 0], pairs[:, 1]])
        j = np.concatenate([pairs[:, 1], pairs[:, 0]])
        keep = _greedy_mis(n, i, j, prio)
        k = int(keep.sum())
        if best is None or abs(k - count) < abs(best[1] - count):
            best = (keep, k, r)
        if abs(k - count) <= tol * count:
            break
        if k > count:
            a = math.log(r)
        else:
            b = math.log(r)
    keep, k, r = best
    logger.info("poisson: radius %.6g -> %d points (asked %d)", r, k, count)
    return np.flatnonzero(keep).astype(np.int64)


def fps_subset(points: np.ndarray, count: int, *, max_work: float = FPS_MAX_WORK) -> np.ndarray:
    """Farthest point sampling (open3d) of *count* points; sorted int64 indices.
    Raises InvalidParameterError when n x count exceeds *max_work*."""
    points, count = _check(points, count)
    work = float(len(points)) * count
    if work > max_work:
        raise InvalidParameterError(f"fps: {len(points)} points x {count} kept = {work:.3g} > {max_work:.3g}; "
                                    "farthest point sampling is O(n x count): run it on a smaller crop")
    import open3d as o3d

    from .distances import ExactIndex

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    out = np.asarray(pc.farthest_point_down_sample(int(count)).points)
    hit, idx = ExactIndex(points).lookup(out)
    if not hit.all():
        raise CloudsieveError(f"fps: {int((~hit).sum())} sampled points not found among the originals")
    return np.unique(idx).astype(np.int64)


def entropy_subset(points: np.ndarray, count: int | None, *, method: str = "km", rule: str = MEMORY_RULE,
                   seed: int = 0, **options) -> np.ndarray:
    """Entropy simplification (KM or FCM) via :func:`cloudsieve.core.simplify.simplify_points`.
    *count* goes to every rule that takes one; with ``threshold`` or ``count=None`` the rule's threshold decides
    the count."""
    from ..core import simplify_points

    kw = dict(options)
    if get_rule(rule).takes_target and count is not None:
        kw["count"] = int(count)
    # compare validated the options once: the unchecked method
    keep = simplify_points.unchecked(np.ascontiguousarray(points, dtype=np.float64), method=method, rule=rule,
                                     seed=seed, **kw)
    keep = np.asarray(keep)
    if keep.dtype == bool:
        keep = np.flatnonzero(keep)
    return np.sort(keep.astype(np.int64))


BASELINES = {
    "random": lambda p, c, seed, **kw: random_subset(p, c, seed=seed),
    "voxel": lambda p, c, seed, **kw: voxel_subset(p, c),
    "poisson": lambda p, c, seed, **kw: poisson_subset(p, c, seed=seed),
    "fps": lambda p, c, seed, **kw: fps_subset(p, c),
}


def run_method(name: str, points: np.ndarray, count: int | None, *, seed: int = 0, rule: str = MEMORY_RULE,
               **options) -> np.ndarray:
    """Run method *name* (``km``, ``fcm`` or a key of :data:`BASELINES`); sorted kept indices."""
    if name in ("km", "fcm"):
        return entropy_subset(points, count, method=name, rule=rule, seed=seed, **options)
    if name not in BASELINES:
        raise InvalidParameterError(f"unknown method {name!r}; choose among km, fcm, {', '.join(BASELINES)}")
    return BASELINES[name](points, count, seed)
