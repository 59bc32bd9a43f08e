"""The ``eliminate`` rule: weighted sample elimination, coverage first, information second.

Yuksel 2015 ("Sample Elimination for Generating Poisson Disk Sample Sets"),
as CGAL's ``poisson_eliminate``: every point gets a crowding weight from its
neighbours closer than 2 r_max::

    w(x) = s(x) * sum over y with d(x, y) < 2 r_max of (1 - d(x, y) / (2 r_max)) ** alpha

and the heaviest point is removed, its neighbours' weights lowered, until
none is left. s(x) in (0, 1] is the information multiplier (below): among
equally crowded points the least informative goes first.

Radius: the cloud is a 2-D manifold in 3-D, so r_max follows Yuksel's 2-D
formula r_max = sqrt(A / (2 sqrt(3) N)) for N kept points on a surface of
area A (the radius of N equal disks packed hexagonally on A; CGAL uses the
same formula but feeds it the bounding-box volume, wrong for surfaces). A is
estimated from the points by :func:`surface_area`.

Priorities: every point gets the weight it had when it was removed. Weights
only decrease as points go, and the heaviest remaining point is always the
next, so priorities are non-increasing along the elimination order, and the
order is exactly "priority descending, ties by lower index first". Keeping
the N points of lowest priority (ties: higher index kept) is therefore the
elimination stopped at N. Across cells (each with its halo, see
:func:`eliminate_order`), one global threshold on the priorities removes in
each cell a prefix of its own elimination order: an exact total count,
comparable across cells because the weight is unit-free and r_max is global.

Information (both switchable):

- ``geometric``: surface variation sigma = l0 / (l0 + l1 + l2) of the
  covariance of the neighbours within max(2 r_max, the radius holding ~16
  input points) (Pauly et al. 2002): 0 on a plane, up to 1/3 for isotropic
  scatter (edges, corners, vegetation); s *= 1 - geometric * 3 sigma.
- ``entropy``: dH of each point in its KM/FCM cluster
  (:func:`cloudsieve.core.score_points`), ranked inside the cluster from 0
  (lowest dH) to 1; s *= 1 - entropy * rank.

Exact duplicates (every copy of a lower-index point) get priority +inf: they
go first and never weigh on the others.

Determinism: the result does not depend on the input order (weights are
summed in a canonical order; only exact copies are told apart by index) nor
on the number of threads; scaling the coordinates scales r_max and leaves
every weight the same up to rounding.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InvalidParameterError, InvalidPointsError
from .entropy import score_points
from .kernels import eliminate as _k
from .kernels import geometry as _g

__all__ = ["eliminate_order", "eliminate", "keep_lowest", "relocate", "point_areas", "elimination_radius"]

logger = logging.getLogger(__name__)

ALPHA = 1.0  # exponent of the weight (Yuksel: 8; measured better here, see the module docstring)
AREA_K = 8  # k of the k-NN area estimate
AREA_SAMPLE = 50_000  # points of the seeded sample the areas are estimated on
GEOMETRIC_POINTS = 16  # input points the covariance ball of the geometric term holds at least
COVER_RADIUS = 0.8  # r_cov / r_max: beyond it the coverage factor falls
COVER_GAMMA = 8.0  # exponent of the coverage factor
COVER_LAMBDA = 10.0  # weight of the squared-error factor
IMPORTANCE_SPAN = 4.0  # bounds of the geometric importance
RELOCATE_STEPS = 1  # restricted Lloyd steps after the elimination (eliminate())


def _points(points, name="points", width=3) -> np.ndarray:
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != width:
        raise InvalidParameterError(f"{name} must have shape (n, {width}), got shape {pts.shape}")
    if not np.issubdtype(pts.dtype, np.number) or np.iscomplexobj(pts):
        raise InvalidParameterError(f"{name} must be real numbers, got dtype {pts.dtype}")
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InvalidPointsError(f"{name} has {int(bad.sum())} non-finite rows, the first at index {first}: "
                                 f"{pts[first].tolist()}")
    return pts


def _target(n: int, ratio, count) -> int:
    if ratio is not None and count is not None:
        raise InvalidParameterError(f"give ratio or count, not both (ratio={ratio!r}, count={count!r})")
    if ratio is not None:
        if not (isinstance(ratio, (int, float, np.floating, np.integer)) and 0 < ratio <= 1):
            raise InvalidParameterError(f"ratio must be in (0, 1], got {ratio!r}")
        return int(round(float(ratio) * n))
    if count is None:
        raise InvalidParameterError("eliminate needs a ratio or a count (or r_max)")
    if int(count) != count or not 0 <= count <= n:
        raise InvalidParameterError(f"count must be an integer in [0, {n}] (the number of points), got {count!r}")
    return int(count)


def _fraction(value, name: str) -> float:
    v = float(value)
    if not (np.isfinite(v) and 0.0 <= v < 1.0):
        raise InvalidParameterError(f"{name} must be in [0, 1), got {value!r}")
    return v


HEX = 2.0 * math.sqrt(3.0)  # area of the hexagon around each disk of radius 1 in a hexagonal packing


def elimination_radius(areas, count: int, *, weight: float = 1.0) -> float:
    """r_max for ``count`` kept points, from the area around each point.

    Yuksel's 2-D radius r = sqrt(A / (2 sqrt(3) N)) packs N disks of radius r
    hexagonally on an area A. A point whose own area a exceeds 2 sqrt(3) r^2
    (an isolated point: nothing else within reach) is kept whatever r is and
    covers no one else's area, so it counts as one kept point, not as a / (2
    sqrt(3) r^2) of them: r solves::

        N = weight * sum over i of min(1, a_i / (2 sqrt(3) r^2))

    (exactly, over the sorted areas). On a uniformly sampled surface this is
    Yuksel's formula; a few far outliers no longer inflate r.

    Parameters
    ----------
    areas : array_like of shape (m,), float >= 0
        Area per point (:func:`point_areas`), of all points or of a uniform
        sample of them (then ``weight`` = points / sample size).
    count : int
        Kept points, >= 1.
    weight : float
        Points each area stands for.

    Returns
    -------
    float
        r_max (inf when every point must be kept: count >= weight * m).
    """
    a = np.asarray(areas, dtype=np.float64).ravel()
    if a.size and (not np.isfinite(a).all() or a.min() < 0):
        raise InvalidParameterError("areas must be finite numbers >= 0")
    if int(count) != count or count < 1:
        raise InvalidParameterError(f"count must be an integer >= 1, got {count!r}")
    if not (np.isfinite(weight) and weight > 0):
        raise InvalidParameterError(f"weight must be a positive number, got {weight!r}")
    a = np.sort(a)[::-1]  # largest first
    m = len(a)
    if count >= weight * m or m == 0 or a[0] == 0:
        return math.inf
    # with the j largest counted as 1 each: N = weight * (j + S_j / (HEX r^2)), S_j the sum of the others
    tail = np.cumsum(a[::-1])[::-1]  # tail[j] = sum of a[j:]
    for j in range(m):
        rest = count / weight - j
        if rest <= 0 or tail[j] == 0:
            break
        r2 = tail[j] / (HEX * rest)
        if a[j] <= HEX * r2 and (j == 0 or a[j - 1] >= HEX * r2):
            return math.sqrt(r2)
    return math.inf


def point_areas(points, *, context=None, k: int = AREA_K, sample: int = AREA_SAMPLE, seed: int = 0,
                workers: int | None = None) -> tuple[np.ndarray, float]:
    """Area around each point of the surface the points sample: pi r_k^2 / k.

    r_k is the distance to the k-th nearest other point; pi r_k^2 / k is an
    unbiased estimate of the area per point of a uniform random sample of a
    plane. Above ``sample`` points (with the context), the areas are those of
    a seeded uniform sample of that many points, neighbours among the sample
    only.

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    context : array_like of shape (q, 3), optional
        Neighbours whose areas are not returned (a cell's halo: no border effect).
    k, sample, seed : int
    workers : int, optional
        Threads of the k-d tree query (the result does not depend on it).

    Returns
    -------
    areas : ndarray of shape (m,), float64
        Areas of the m sampled points (m = n without sampling).
    weight : float
        Points each area stands for (n / m), as :func:`elimination_radius` takes it.
    """
    pts = _points(points)
    ctx = np.zeros((0, 3)) if context is None else _points(context, "context")
    if int(k) != k or k < 1:
        raise InvalidParameterError(f"k must be an integer >= 1, got {k!r}")
    if int(sample) != sample or sample < k + 1:
        raise InvalidParameterError(f"sample must be an integer >= k + 1 = {k + 1}, got {sample!r}")
    return _areas(pts, ctx, int(k), int(sample), seed, workers or -1)


def _areas(pts, ctx, k, sample, seed, workers):
    n, q = len(pts), len(ctx)
    if n + q > sample:
        pick = np.sort(np.random.default_rng(seed).choice(n + q, sample, replace=False))
        own = pick[pick < n]
        allp = np.concatenate([pts[own], ctx[pick[pick >= n] - n]])
        f = sample / (n + q)
    else:
        allp = np.concatenate([pts, ctx]) if q else pts
        own = np.arange(n)
        f = 1.0
    m = len(own)
    if m == 0:
        return np.zeros(0), 1.0
    if len(allp) < k + 1:
        return np.full(m, math.inf), n / m
    d = cKDTree(allp).query(allp[:m], k=k + 1, workers=workers)[0][:, k]
    # the sample is thinner by f: its areas are 1/f times the points' own
    return np.pi * np.square(d) / k * f, n / m


class _Grid:
    """Points (points, then halo, then fixed) in the canonical internal order: grid cells of size >= h
    along a Z-order curve, inside a cell by coordinates, exact copies by position."""

    def __init__(self, allp: np.ndarray, h: float):
        lo = allp.min(axis=0)
        span = float((allp.max(axis=0) - lo).max())
        h = max(h, span / (2.0**21 - 2), 1e-300)  # < 2^21 cells per axis
        codes = _k.cell_codes(allp, lo, h)
        order = np.argsort(codes, kind="stable")
        sc = codes[order]
        new = np.ones(len(sc), dtype=bool)
        new[1:] = sc[1:] != sc[:-1]
        cstart = np.append(np.flatnonzero(new), len(sc)).astype(np.int64)
        if np.diff(cstart).max(initial=0) > 64:  # a crowded cell: one sort instead of insertion sorts
            order = np.lexsort((np.arange(len(sc)), allp[:, 2], allp[:, 1], allp[:, 0], codes))
        else:
            _k.sort_cells(allp, codes, order)
        self.order = order
        self.P = np.ascontiguousarray(allp[order])
        self.cell = np.cumsum(new) - 1
        self.cstart = cstart
        self.nstart, self.ncells = _k.cell_neighbours(sc[new])
        self.h = h
        same = np.zeros(len(sc), dtype=bool)  # exact copies of the previous row (same cell, adjacent)
        same[1:] = ~new[1:] & (self.P[1:] == self.P[:-1]).all(axis=1)
        self.copy = same

    def args(self):
        return self.P, self.cell, self.cstart, self.nstart, self.ncells


def _ranks_in_groups(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Rank of each value inside its group, scaled to [0, 1] (0 lowest; ties by index)."""
    n = len(values)
    o = np.lexsort((np.arange(n), values, groups))
    g = groups[o]
    start = np.r_[0, np.flatnonzero(g[1:] != g[:-1]) + 1]
    size = np.diff(np.r_[start, n])
    first = np.repeat(start, size)
    pos = np.arange(n) - first
    out = np.empty(n)
    out[o] = pos / np.maximum(np.repeat(size, size) - 1, 1)
    return out


def eliminate_order(points, *, r_max=None, ratio=None, count=None, labels=None, dh=None, halo=None,
                    fixed=None, alpha: float = ALPHA, coverage: bool = True, geometric: float = 0.0,
                    entropy: float = 0.0, floor: int = 0, threads: int | None = None) -> np.ndarray:
    """Priority of every point in the elimination order (larger goes first).

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    r_max : float, optional
        The Poisson-disk radius (neighbours weigh within 2 r_max). Default:
        ``elimination_radius(*point_areas(points, context=halo), N)`` for the
        kept count N of ``ratio`` or ``count``. Cells of one cloud must share
        one r_max (from the whole cloud's areas and count) for their
        priorities to compare.
    ratio, count : optional
        The kept share in (0, 1] or count (one of them), for r_max only.
    labels : array_like of shape (n,), int, optional
        KM/FCM cluster of each point: with ``entropy`` > 0 and no ``dh``, dH is
        computed in these clusters (:func:`cloudsieve.core.score_points`).
    dh : array_like of shape (n,), float, optional
        dH of each point in its cluster (ranked inside ``labels``' clusters).
    halo : array_like of shape (h, 3), optional
        Points of the neighbouring cells: eliminated with the points (so the
        border sees the density it will have) but given no priority; their
        own cell decides them.
    fixed : array_like of shape (f, 3), optional
        Points that weigh on the others and are never removed.
    alpha : float
        Exponent of the weight, > 0 (Yuksel: 8).
    coverage : bool
        Also weigh the coverage and squared-error terms (module docstring).
    geometric, entropy : float in [0, 1)
        Strength of the information terms (0: off).
    floor : int
        Stop when this many points are left (they get their last stored
        keys, upper bounds that keep the order consistent); 0: a full order.
    threads : int, optional
        numba threads of the parallel passes (None: numba's default). The
        result does not depend on it.

    Returns
    -------
    ndarray of shape (n,), float64
        The key of each point when it was removed: +inf for exact copies of a
        lower-index point, >= 0 otherwise. Removal order: priority descending,
        ties lower index first (:func:`keep_lowest` keeps the last ones).
    """
    pts = _points(points)
    n = len(pts)
    hal = np.zeros((0, 3)) if halo is None else _points(halo, "halo")
    fix = np.zeros((0, 3)) if fixed is None else _points(fixed, "fixed")
    if not (np.isfinite(alpha) and alpha > 0):
        raise InvalidParameterError(f"alpha must be a positive number, got {alpha!r}")
    geometric = _fraction(geometric, "geometric")
    entropy = _fraction(entropy, "entropy")
    if int(floor) != floor or not 0 <= floor <= n:
        raise InvalidParameterError(f"floor must be an integer in [0, {n}], got {floor!r}")
    lab = None
    if labels is not None:
        lab = np.asarray(labels)
        if lab.shape != (n,) or (n and not np.issubdtype(lab.dtype, np.integer)):
            raise InvalidParameterError(f"labels must be integers of shape ({n},), got {lab.dtype} {lab.shape}")
    if dh is not None:
        dh = np.asarray(dh, dtype=np.float64)
        if dh.shape != (n,) or np.isnan(dh).any():
            raise InvalidParameterError(f"dh must be numbers of shape ({n},) without NaN, got shape {dh.shape}")
    if entropy > 0 and dh is None and lab is None:
        raise InvalidParameterError("the entropy term needs labels or dh; give labels= or set entropy=0")
    if r_max is None:
        target = _target(n, ratio, count)
        r_max = _radius(pts, hal, target, threads) if target else math.inf
    elif not (isinstance(r_max, (int, float, np.floating, np.integer)) and r_max > 0):
        raise InvalidParameterError(f"r_max must be a positive number, got {r_max!r}")
    if n == 0:
        return np.zeros(0)
    rank = None
    if entropy > 0:
        if dh is None:
            dh = score_points(pts, lab, workers=threads).delta_h
        rank = _ranks_in_groups(dh, np.zeros(n, dtype=np.int64) if lab is None else lab.astype(np.int64))
    with _threads(threads):
        return _order(pts, hal, fix, float(r_max), float(alpha), coverage, geometric, rank, entropy, int(floor))


def _radius(pts, hal, target, threads) -> float:
    areas, wt = _areas(pts, hal, AREA_K, AREA_SAMPLE, 0, threads or -1)
    return elimination_radius(areas, target, weight=wt) if len(areas) else math.inf


class _threads:
    """Context: numba's thread count set to ``threads`` (None: unchanged)."""

    def __init__(self, threads):
        self.threads = threads

    def __enter__(self):
        import numba

        self.old = numba.get_num_threads()
        if self.threads is not None:
            numba.set_num_threads(max(1, min(int(self.threads), numba.config.NUMBA_NUM_THREADS)))

    def __exit__(self, *exc):
        import numba

        numba.set_num_threads(self.old)


def _order(pts, hal, fix, r_max, alpha, coverage, geometric, rank, entropy, floor) -> np.ndarray:
    n, nh = len(pts), len(hal)
    allp = np.concatenate([pts, hal, fix]) if len(hal) or len(fix) else pts
    if not math.isfinite(r_max):  # every point is kept: none weighs on another
        r_max = 0.0
    two_r = 2.0 * r_max
    rho = two_r
    if geometric > 0:  # covariance ball: 2 r_max, or wider to hold ~GEOMETRIC_POINTS input points
        areas, _ = _areas(pts, hal, AREA_K, AREA_SAMPLE, 0, -1)
        if len(areas) and np.isfinite(areas).all():
            rho = max(two_r, math.sqrt(GEOMETRIC_POINTS * float(np.median(areas)) / math.pi))
    grid = _Grid(allp, max(two_r, rho, 1e-300))
    src = grid.order  # internal row -> position in allp
    state = np.where(src < n + nh, 1, 2).astype(np.uint8)
    state[grid.copy] = 0
    scale = np.ones(len(allp))
    imp2 = np.ones(len(allp))
    if geometric > 0:
        imp2 = _importance(_g.surface_variation(*grid.args(), state, rho, 4), state, geometric) ** 2
    if rank is not None:
        inner = src < n
        scale[inner] *= 1.0 - entropy * rank[src[inner]]
    ialpha = int(alpha) if alpha == int(alpha) and alpha <= 64 else -1
    w = _k.initial_weights(*grid.args(), state, scale, two_r, alpha, ialpha)
    r_cov, lam = (COVER_RADIUS * r_max, COVER_LAMBDA) if coverage and r_max > 0 else (0.0, 0.0)
    # floor counts points only; halo points left with them are simply not removed
    left = floor + int(((state == 1) & (src >= n)).sum()) if floor else 0
    prio, _stats = _k.eliminate(*grid.args(), state, scale, imp2, w, src.astype(np.int64), two_r, alpha, ialpha, r_cov,
                        COVER_GAMMA, lam, left)
    out = np.empty(len(allp))
    out[src] = prio
    out = out[:n]
    out[np.isnan(out)] = np.inf  # exact copies
    return out


def _importance(sigma, state, beta) -> np.ndarray:
    """(sigma / median sigma) ** beta, within [1 / IMPORTANCE_SPAN, IMPORTANCE_SPAN]."""
    alive = sigma[state != 0]
    med = float(np.median(alive)) if len(alive) else 0.0
    if not med > 0:
        return np.ones(len(sigma))
    return np.clip((np.maximum(sigma, 1e-12) / med) ** beta, 1.0 / IMPORTANCE_SPAN, IMPORTANCE_SPAN)


def relocate(points, keep, r_max: float, *, halo=None, halo_keep=None, iterations: int = RELOCATE_STEPS,
             threads: int | None = None) -> np.ndarray:
    """Restricted Lloyd steps on a kept set: lower squared error, same count.

    Each kept point moves to the point of its Voronoi region (the points
    nearest to it) nearest the region's centroid, unless some point of the
    region would end farther from it than both its current farthest and
    r_max (the coverage stays). Kept halo points weigh but do not move.

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    keep : array_like of shape (n,), bool
    r_max : float
        The elimination radius (:func:`elimination_radius`).
    halo : array_like of shape (h, 3), optional
    halo_keep : array_like of shape (h,), bool, optional
        Which halo points are kept (default none).
    iterations : int
    threads : int, optional

    Returns
    -------
    ndarray of shape (n,), bool
        The new keep mask (as many points).
    """
    pts = _points(points)
    n = len(pts)
    kp = np.asarray(keep)
    if kp.shape != (n,) or kp.dtype != bool:
        raise InvalidParameterError(f"keep must be a bool mask of shape ({n},), got {kp.dtype} {kp.shape}")
    hal = np.zeros((0, 3)) if halo is None else _points(halo, "halo")
    hk = np.zeros(len(hal), dtype=bool) if halo_keep is None else np.asarray(halo_keep)
    if hk.shape != (len(hal),) or hk.dtype != bool:
        raise InvalidParameterError(f"halo_keep must be a bool mask of shape ({len(hal)},), got {hk.dtype} {hk.shape}")
    if not (isinstance(r_max, (int, float, np.floating, np.integer)) and r_max > 0):
        raise InvalidParameterError(f"r_max must be a positive number, got {r_max!r}")
    if int(iterations) != iterations or iterations < 0:
        raise InvalidParameterError(f"iterations must be an integer >= 0, got {iterations!r}")
    if n == 0 or not kp.any() or not math.isfinite(r_max) or iterations == 0:
        return kp.copy()
    with _threads(threads):
        return _relocate(pts, kp, hal, hk, float(r_max), int(iterations))


def _relocate(pts, kp, hal, hk, r_max, iterations) -> np.ndarray:
    n = len(pts)
    allp = np.concatenate([pts, hal]) if len(hal) else pts
    grid = _Grid(allp, 2.0 * r_max)
    src = grid.order
    kept = np.concatenate([kp, hk])[src].astype(np.uint8)
    movable = (src < n).astype(np.uint8)
    movable[grid.copy] = 0
    for _ in range(iterations):
        near = _k.nearest_kept(*grid.args(), kept)
        new = _k.relocate(grid.P, near, kept, movable, r_max * r_max)
        if np.array_equal(new, kept):
            break
        kept = new
    out = np.empty(len(allp), dtype=bool)
    out[src] = kept.astype(bool)
    return out[:n]


def keep_lowest(priority, count: int) -> np.ndarray:
    """Keep mask (n,) bool of the ``count`` points removed last: lowest priority, ties by higher index.

    Over the priorities of many cells concatenated in point-index order, the
    same call is the one global threshold.
    """
    p = np.asarray(priority, dtype=np.float64)
    if p.ndim != 1:
        raise InvalidParameterError(f"priority must have shape (n,), got shape {p.shape}")
    n = len(p)
    if int(count) != count or not 0 <= count <= n:
        raise InvalidParameterError(f"count must be an integer in [0, {n}], got {count!r}")
    keep = np.zeros(n, dtype=bool)
    if count:
        keep[np.lexsort((-np.arange(n), p))[: int(count)]] = True
    return keep


def eliminate(points, count=None, *, ratio=None, r_max=None, relocate_steps: int = RELOCATE_STEPS,
              threads: int | None = None, **options) -> np.ndarray:
    """Sorted int64 indices of exactly ``count`` (or round(ratio * n)) points of a whole cloud.

    The elimination (:func:`eliminate_order`) stops at the count, then
    ``relocate_steps`` restricted Lloyd steps (:func:`relocate`) lower the
    squared error. ``options``: ``labels``, ``dh``, ``fixed``, ``alpha``,
    ``coverage``, ``geometric``, ``entropy`` as in :func:`eliminate_order`.
    """
    pts = _points(points)
    n = len(pts)
    target = _target(n, ratio, count)
    bad = set(options) - {"labels", "dh", "fixed", "alpha", "coverage", "geometric", "entropy"}
    if bad:
        raise InvalidParameterError(f"eliminate() got unexpected options {sorted(bad)} (halo and floor belong to "
                                    "eliminate_order, for cells)")
    if r_max is None:
        r_max = _radius(pts, np.zeros((0, 3)), target, threads) if target else math.inf
    prio = eliminate_order(pts, r_max=r_max, floor=target, threads=threads, **options)
    keep = keep_lowest(prio, target)
    if relocate_steps and math.isfinite(r_max):
        keep = relocate(pts, keep, r_max, iterations=relocate_steps, threads=threads)
    return np.flatnonzero(keep).astype(np.int64)
