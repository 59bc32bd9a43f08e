"""The elimination radius r_max of the ``eliminate`` rule, from the area around each point.

Yuksel 2015: N disks of radius r_max packed hexagonally cover A = 2 sqrt(3) N r_max^2,
with A the sampled surface's area (:func:`point_areas`), not the bounding box.
An isolated point counts as one kept point (:func:`elimination_radius`), so a few
far points do not inflate r_max. Both steps are sums over points: a driver can
compute areas per cell and solve for one global r_max.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..chunk import take_rows, xyz_bounds
from ..errors import InvalidParameterError
from ..params import check
from .cellgrid import CellGrid, check_points
from .duplicates import first_rows
from .kernels import area_knn as _ka
from .kernels import grid as _kg

__all__ = ["point_areas", "elimination_radius", "global_radius", "AREA_K", "AREA_SAMPLE", "HEX"]

AREA_K = 8  # k of the k-NN area estimate
AREA_SAMPLE = 50_000  # points of the seeded sample the areas are estimated on
HEX = 2.0 * math.sqrt(3.0)  # area of the hexagon around a disk of radius 1 in a hexagonal packing


def point_areas(points, *, context=None, k: int = AREA_K, sample: int = AREA_SAMPLE,
                seed: int = 0) -> tuple[np.ndarray, float]:
    """Area around each point of the sampled surface: pi r_k^2 / k (r_k: k-th nearest other point).

    Above ``sample`` points (>= k + 1, with context), areas come from a seeded uniform
    sample, scaled by the sampling rate. ``context`` (q, 3): neighbours whose areas are
    not returned (a cell's halo).

    Returns
    -------
    areas : ndarray (m,), float64
        Areas of the m sampled points; inf when fewer than k + 1 points in all.
    weight : float
        Points each area stands for (n / m).
    """
    pts = check_points(points)
    ctx = np.zeros((0, 3)) if context is None else check_points(context, "context")
    if int(k) != k or k < 1:
        raise InvalidParameterError(f"k must be an integer >= 1, got {k!r}")
    if int(sample) != sample or sample < k + 1:
        raise InvalidParameterError(f"sample must be an integer >= k + 1 = {k + 1}, got {sample!r}")
    return areas_of(pts, ctx, int(k), int(sample), seed)


def areas_of(pts: np.ndarray, ctx: np.ndarray, k: int, sample: int, seed: int):
    """:func:`point_areas` on valid arrays."""
    n, q = len(pts), len(ctx)
    if n + q > sample:
        pick = np.sort(np.random.default_rng(seed).choice(n + q, sample, replace=False))
        own = pick[pick < n]
        allp = np.concatenate([take_rows(pts, own), ctx[pick[pick >= n] - n]])
        rate = sample / (n + q)
    else:
        allp = np.concatenate([pts, ctx]) if q else pts
        own = np.arange(n)
        rate = 1.0
    m = len(own)
    if m == 0:
        return np.zeros(0), 1.0
    if len(allp) < k + 1:
        return np.full(m, math.inf), n / m
    d = _kth_other(np.ascontiguousarray(allp), m, k)
    return np.pi * np.square(d) / k * rate, n / m  # the sample is thinner by `rate`


def _kth_other(allp: np.ndarray, m: int, k: int) -> np.ndarray:
    """Distance from each of the first m rows of allp (>= k + 1 rows) to its k-th nearest other row.

    Searched on the distinct rows (a pile of c copies would cost c^2 distances),
    counting each row's copies.
    """
    first = first_rows(allp)
    lead = np.flatnonzero(first == np.arange(len(allp)))  # the distinct rows, in order (all: mult 1)
    group = np.searchsorted(lead, first)  # each row's distinct row
    mult = np.bincount(group, minlength=len(lead))
    if len(lead) == 1:  # one spot: every row has its k others (>= k + 1 rows) at distance 0
        return np.zeros(m)
    asked = np.zeros(len(lead), dtype=bool)  # the distinct rows asked for, ascending (np.unique's answer; numpy
    asked[group[:m]] = True  # 2.4's np.unique of integers is a hundred times slower than a mask)
    q = np.flatnonzero(asked)
    rows = take_rows(allp, lead)
    kk = min(k + 1, len(lead))  # self and k others (or all the distinct rows there are)
    d, i = _nearest(rows, q, kk)
    out = np.zeros(len(lead))
    out[q] = _ka.kth_others(d, i, q, mult, k)  # self: first unless another distinct row is at a distance that
    # rounds to 0; a row whose copies already make k others is at distance 0
    return out[group[:m]]


def global_radius(sample: np.ndarray, n: int, target: int) -> float:
    """The one r_max of a cloud of *n* points keeping *target*, from a uniform sample (S, 3) of it.

    Sample areas scaled by S / n, each standing for n / S points, go to
    :func:`elimination_radius`. Returns inf when every point is kept (or *target* is 0).
    """
    s = len(sample)
    if target <= 0 or s == 0:
        return math.inf
    areas, weight = point_areas(sample)
    return float(elimination_radius(areas * (s / n), int(target), weight=weight * n / s))


#: mean points per cell at the first grid's side, reached in at most OCCUPANCY_STEPS guesses
OCCUPANCY = 6.0
OCCUPANCY_STEPS = 6
#: at most this many points left unsure are searched against every row (a few far points: no grid to build)
FEW = 64
#: more than this many points times k in the 27 cells around: search a grid 8 times finer
CROWD = 64
#: the grid's reach as a fraction of its side: a k-th distance below it is sure
REACH = 1.0 - 1e-6


def _nearest(rows: np.ndarray, q: np.ndarray, kk: int) -> tuple[np.ndarray, np.ndarray]:
    """``cKDTree(rows).query(rows[q], k=kk)`` for distinct *rows* (>= 2): same distances, ties in any order.

    On :class:`.cellgrid.CellGrid` grids (importing ``scipy.spatial`` costs more than
    small runs); unsure answers go to coarser grids, crowded cells (:data:`CROWD`)
    to finer ones first.
    """
    m = len(rows)
    lo, hi = xyz_bounds(rows)
    span = float((hi - lo).max())  # > 0: two distinct rows at least
    side, finest = span * math.sqrt(kk / m), max(span * 2.0**-20, 1e-300)  # as CellGrid bounds its side
    for _ in range(OCCUPANCY_STEPS):  # about OCCUPANCY points a cell, as on a surface (the usual cloud)
        codes = np.sort(_kg.cell_codes(rows, lo, side))  # the occupied cells by a sort: np.unique is slower
        o = m / (np.count_nonzero(codes[1:] != codes[:-1]) + 1)
        if OCCUPANCY / 2 <= o <= 2 * OCCUPANCY:
            break
        side = max(side * math.sqrt(OCCUPANCY / o), finest)
    d, i = np.empty((len(q), kk)), np.empty((len(q), kk), dtype=np.int64)
    coarser: dict[int, list] = {}

    def ask(at: np.ndarray, level: int, crowd: int) -> tuple[np.ndarray, np.ndarray]:
        """Search positions *at* of q on the grid of side ``side * 2**level``; store sure answers, return (searched, statuses)."""
        grid = CellGrid(rows, side * 2.0**level)
        inv = np.empty(m, dtype=np.int64)
        inv[grid.order] = np.arange(m)
        g = inv[q[at]]
        o = np.argsort(g)  # in the grid's order: the searches walk memory in order
        at, g = at[o], g[o]
        dd, ii, status = _ka.nearest_rows(*grid.args(), g, kk, (REACH * grid.h) ** 2, crowd, len(grid.cstart) == 2,
                                          numba.get_num_threads(), grid.lo, grid.h)
        _ka.store_sure(d, i, at, dd, ii, status, grid.order)
        unsure = np.flatnonzero(status == 1)  # to the grid that surely covers its k-th distance so far
        far = np.sqrt(dd[unsure, -1]) / (REACH * side)  # inf: fewer than kk found, 4 times coarser
        with np.errstate(divide="ignore"):
            up = np.where(np.isfinite(far), np.ceil(np.log2(far)), level + 2)
        up = np.maximum(up, level + 1).astype(np.int64)
        for lv in np.unique(up).tolist():
            coarser.setdefault(lv, []).append(at[unsure[up == lv]])
        return at, status

    at, level = np.arange(len(q)), 0
    while len(at):  # the crowded to finer grids, while there are finer ones
        fine = side * 2.0 ** (level - 3) > finest
        at, status = ask(at, level, CROWD * kk if fine else -1)
        at, level = at[status == 2], level - 3
    while coarser:  # the unsure to coarser grids: a grid of one cell holds every point
        level = min(coarser)
        at = np.concatenate(coarser.pop(level))
        if len(at) > FEW:
            ask(at, level, -1)
        elif len(at):  # every row searched, without a grid
            one = np.zeros(1, dtype=np.int64)
            dd, i[at], _ = _ka.nearest_rows(rows, np.zeros(m, dtype=np.int64), np.array([0, m]), np.array([0, 1]),
                                            one, q[at], kk, math.inf, -1, True)
            d[at] = np.sqrt(dd)
    return d, i


def elimination_radius(areas, count: int, *, weight=1.0) -> float:
    """r_max for ``count`` (>= 1) kept points: r solving N = sum_i weight_i * min(1, a_i / (2 sqrt(3) r^2)).

    On a uniform surface of area A, Yuksel's sqrt(A / (2 sqrt(3) N)); solved exactly
    over the sorted areas. ``areas`` (m,) >= 0 (inf allowed); ``weight``: points each
    area stands for (a float or one per area). Returns inf when every point is kept or
    every point is isolated.
    """
    a = np.asarray(areas, dtype=np.float64).ravel()
    if a.size and (np.isnan(a).any() or a.min() < 0):
        raise InvalidParameterError("areas must be numbers >= 0")
    count = check("count", count)  # the option's one check (params)
    w = np.broadcast_to(np.asarray(weight, dtype=np.float64), a.shape) if np.ndim(weight) else \
        np.full(a.shape, float(weight))
    if w.shape != a.shape or not (np.isfinite(w).all() and (w > 0).all()):
        raise InvalidParameterError(f"weight must be positive numbers, one or one per area ({a.size}), "
                                    f"got shape {np.shape(weight)}")
    return radius_of(a, count, w)


def radius_of(a: np.ndarray, count: int, weight) -> float:
    """:func:`elimination_radius` on valid input (weight: a number or one per area)."""
    m = len(a)
    if np.ndim(weight) == 0:
        return _radius_uniform(a, count, float(weight))
    w = np.asarray(weight, dtype=np.float64)
    if m == 0 or count >= w.sum():
        return math.inf
    o = np.argsort(-a, kind="stable")  # largest first; with the j largest counted as 1 each:
    a, w = a[o], w[o]  # N = sum(w[:j]) + sum(w[j:] a[j:]) / (HEX r^2)
    head = np.r_[0.0, np.cumsum(w)]
    wa = w * a
    tail = np.r_[np.cumsum(np.where(np.isfinite(wa), wa, 0.0)[::-1])[::-1], 0.0]
    for j in range(m):
        rest = count - head[j]
        if rest <= 0:
            break
        if not math.isfinite(a[j]) or not tail[j] > 0:
            continue
        r2 = tail[j] / (HEX * rest)
        if a[j] <= HEX * r2 and (j == 0 or a[j - 1] >= HEX * r2):
            return math.sqrt(r2)
    return math.inf


def _radius_uniform(a: np.ndarray, count: int, weight: float) -> float:
    """radius_of with one weight for every area."""
    m = len(a)
    if m == 0 or count >= weight * m:
        return math.inf
    a = np.sort(a)[::-1]  # largest first; with the j largest counted as 1 each:
    tail = np.cumsum(a[::-1])[::-1]  # N / weight = j + tail[j] / (HEX r^2), tail[j] = sum of a[j:]
    for j in range(m):
        rest = count / weight - j
        if rest <= 0 or not tail[j] > 0:
            break
        if not math.isfinite(tail[j]):
            continue
        r2 = tail[j] / (HEX * rest)
        if a[j] <= HEX * r2 and (j == 0 or a[j - 1] >= HEX * r2):
            return math.sqrt(r2)
    return math.inf
