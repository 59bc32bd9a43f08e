"""The ``eliminate`` rule: weighted sample elimination, coverage first, information second.

Yuksel 2015 ("Sample Elimination for Generating Poisson Disk Sample Sets";
CGAL's ``poisson_eliminate``): every point gets a crowding weight from its
neighbours closer than 2 r_max, the heaviest point goes, its neighbours get
lighter, until the count is reached. Here the key of a point x is::

    key(x) = w(x) * f(x)
    w(x)   = sum over remaining y with d(x, y) < 2 r_max of (1 - d(x, y) / (2 r_max)) ** alpha
    f(x)   = g(e(x)) / (1 + lam * c(x) / r_max^2)

- w is Yuksel's crowding weight, with alpha = 1 by default (Yuksel and CGAL
  use 8; on the shared scans alpha = 1 gave lower point RMS and max errors at
  every ratio, e.g. bun_zipper at 20%: RMS 0.975x / max 1.04x the best
  baseline against 0.999x / 1.13x with alpha = 8);
- f is the coverage term: x represents itself and every removed point whose
  nearest remaining point it is; e(x) is the largest distance one of them
  would have to its nearest remaining point if x went, c(x) the sum of the
  squared distances they would gain; g(e) = 1 up to r_cov = 0.8 r_max, then
  (r_cov / e)^8; lam = 10. Plain WSE leaves holes (point max 1.35-1.86x the
  best of voxel/Poisson/farthest point on the shared scans); with f, 1.02-1.16x.

The information terms (an entropy rank and a geometric importance
multiplying the key) were measured and removed: they did not lower the
errors (docs/benchmarks.md, "Quality: weighted sample elimination"); the
compiled loop still takes their per-point factors, all 1.

r_max: :mod:`.radius` (from the area of the sampled surface and the count). The elimination loop
on a grid, its constants and :func:`keep_lowest` are in :mod:`.elimination` (shared with
:mod:`.eliminate_cells`).

Priorities: each point gets its key when it was removed. Keys only decrease
as points go and the largest is always next, so priorities are
non-increasing along the removals, and the removal order is exactly
"priority descending, ties lower index first": keeping the N points of
lowest priority (:func:`keep_lowest`) is the elimination stopped at N.
Across cells (each run with its halo, :func:`eliminate_order`) with one
global r_max, one global threshold on all priorities removes a prefix of each
cell's own order: an exact total count, ties by point index.

After the count is reached, :func:`.relocate.relocate` moves each kept
point to the point of its Voronoi region nearest the region's centroid (one
restricted Lloyd step; lower squared error, coverage kept); :func:`eliminate`
does both for a whole cloud in memory (over cells on threads above
``cell_points`` points, :mod:`.eliminate_cells`), and
:func:`.eliminate_cells.eliminate_cell` for one cell of a cloud with its halo.

Exact duplicates (every copy of a lower-index point) get priority +inf: they
go first and never weigh on the others. The result does not depend on the
input order (sums run in the canonical order of :class:`.cellgrid.CellGrid`;
only exact copies are told apart, by index) nor on the thread count.
"""

from __future__ import annotations

import logging
import math

import numba
import numpy as np

from ..errors import InvalidParameterError
from ._validation import ratio_count
from .cellgrid import CellGrid, check_points
from .kernels import neighbours as _kn
from .elimination import ALPHA, alpha_int, area_radius, keep_lowest, run_elimination
from .relocate import RELOCATE_STEPS, check_r_max, numba_threads, relocate, relocate_points

__all__ = ["CELL_POINTS", "MIN_CELL_POINTS", "eliminate_order", "eliminate", "keep_lowest", "relocate"]

logger = logging.getLogger(__name__)

#: eliminate() runs over cells of at most this many points above it (module .eliminate_cells). At 1 M points and
#: 50% kept on 2 threads (load 0.5), the cells stage took 0.67 s with cells of 8,192 points, 0.70 s with 16,384,
#: 0.79 s with 32,768, 0.83 s with 65,536 (one elimination: 2.2 s): smaller cells fit the caches, but the halos
#: and calls grow
CELL_POINTS = 16_384
MIN_CELL_POINTS = 1_024  # the smallest cell_points accepted: below it the halos outweigh the cells


def _target(n: int, ratio, count) -> int:
    if ratio is not None and count is not None:
        raise InvalidParameterError(f"give ratio or count, not both (ratio={ratio!r}, count={count!r})")
    if ratio is not None:
        if not (isinstance(ratio, (int, float, np.integer, np.floating)) and 0 < ratio <= 1):
            raise InvalidParameterError(f"ratio must be in (0, 1], got {ratio!r}")
        return ratio_count(ratio, n)
    if count is None:
        raise InvalidParameterError("the eliminate rule needs a ratio or a count (or r_max)")
    if int(count) != count or not 0 <= count <= n:
        raise InvalidParameterError(f"count must be an integer in [0, {n}] (the number of points), got {count!r}")
    return int(count)


def eliminate_order(points, *, r_max=None, ratio=None, count=None, halo=None, fixed=None, gone=None,
                    alpha: float = ALPHA, coverage: bool = True, floor: int = 0, threads: int | None = None,
                    halo_left: bool = False):
    """Priority of every point in the elimination order (larger goes first).

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    r_max : float, optional
        The Poisson-disk radius (:func:`cloudsieve.core.radius.elimination_radius`);
        inf: every point is kept (all priorities 0). Default: from the areas
        of ``points`` (halo as context) and the count of ``ratio``/``count``.
        Cells of one cloud must share one r_max for their priorities to compare.
    ratio, count : optional
        The kept share in (0, 1] or count (one of them): for r_max only.
    halo : array_like of shape (h, 3), optional
        Points of the neighbouring cells: eliminated with the points (the
        border sees the density it will have) but given no priority.
    fixed : array_like of shape (f, 3), optional
        Points that weigh on the others and are never removed.
    gone : array_like of shape (g, 3), optional
        Points already removed (a neighbouring cell's): they do not weigh,
        but each is represented from the start by its nearest point (of
        ``points``, ``halo``, ``fixed``; within 2 r_max), as if it had just
        gone, so the coverage term sees the area they leave uncovered.
        Exact copies of a point (of any of the four) are not: like the
        copies among ``points``, they never weigh.
    alpha : float
        Exponent of the crowding weight, > 0.
    coverage : bool
        Use the coverage term f (module docstring); False: plain WSE.
    floor : int
        Stop when this many of the points are left (the halo's points are
        eliminated along but do not count); the points left get their keys at
        the stop (the keys they would be removed with next, <= every removed
        key). 0: a full order. Keeping the ``floor`` lowest
        (:func:`keep_lowest`) is exactly the elimination stopped at ``floor``
        points, with or without halo.
    threads : int, optional
        numba threads of the parallel passes (None: numba's setting); the
        result does not depend on it.
    halo_left : bool
        Also return which halo points are left at the stop (``floor`` > 0).

    Returns
    -------
    ndarray of shape (n,), float64
        Key at removal: +inf for exact copies of a lower-index point, >= 0
        otherwise. Removal order: priority descending, ties lower index first.
    left : ndarray of shape (h,), bool
        Only with ``halo_left``: the halo points not removed (nor exact copies).
    """
    out = _eliminate_order(points, r_max, ratio, count, halo, fixed, alpha, coverage, floor, threads, gone)
    return (out[0], out[2]) if halo_left else out[0]


def _eliminate_order(points, r_max, ratio, count, halo, fixed, alpha, coverage, floor, threads, gone=None) -> tuple:
    """:func:`eliminate_order`, the grid of its points (None when there is none), the halo points left, each
    grid row's nearest point left (-1: not known; None without the coverage term)."""
    pts = check_points(points)
    n = len(pts)
    hal = np.zeros((0, 3)) if halo is None else check_points(halo, "halo")
    fix = np.zeros((0, 3)) if fixed is None else check_points(fixed, "fixed")
    gon = np.zeros((0, 3)) if gone is None else check_points(gone, "gone")
    if not (isinstance(alpha, (int, float, np.integer, np.floating)) and math.isfinite(alpha) and alpha > 0):
        raise InvalidParameterError(f"alpha must be a positive number, got {alpha!r}")
    if int(floor) != floor or not 0 <= floor <= n:
        raise InvalidParameterError(f"floor must be an integer in [0, {n}], got {floor!r}")
    if r_max is None:
        target = _target(n, ratio, count)
        r_max = area_radius(pts, hal, target)
    else:
        r_max = check_r_max(r_max)
    if n == 0:
        return np.zeros(0), None, np.ones(len(hal), dtype=bool), None
    with numba_threads(threads):
        return _order(pts, hal, fix, gon, r_max, float(alpha), bool(coverage), int(floor))


def _order(pts, hal, fix, gon, r_max, alpha, coverage, floor) -> tuple:
    n, nh, nf = len(pts), len(hal), len(fix)
    if not math.isfinite(r_max):  # every point is kept: nobody weighs on anybody
        allp = np.concatenate([pts, hal, fix]) if nh or nf else pts
        grid = CellGrid(allp, 0.0)
        out = np.zeros(len(allp))
        out[grid.order[grid.copy]] = np.inf
        return out[:n], None, np.isfinite(out[n : n + nh]) if nh else np.ones(0, dtype=bool), None
    allp = np.concatenate([pts, hal, fix, gon]) if nh or nf or len(gon) else pts
    two_r = 2.0 * r_max
    grid = CellGrid(allp, two_r)
    src = grid.order  # internal row -> position in allp
    state = np.where(src < n + nh, 1, np.where(src < n + nh + nf, 2, 0)).astype(np.uint8)
    state[grid.copy] = 0
    gone_rep = np.full(len(allp), -1, dtype=np.int64)
    if len(gon) and coverage:  # the gone points: represented by their nearest alive point; their exact
        # copies are not (they weigh on nobody, as the cell that removed them counted them)
        rows = np.flatnonzero((src >= n + nh + nf) & ~grid.copy)
        gone_rep[rows] = grid.nearest_kept((state != 0).astype(np.uint8), rows)
    ones = np.ones(len(allp))  # the key's factors of the removed information terms (module docstring)
    ialpha = alpha_int(alpha)
    lists = _kn.build_lists(*grid.args(), grid.order, state, two_r, alpha, ialpha, coverage)
    prio, rep = run_elimination(grid, lists, state, n, gone_rep, r_max, alpha, coverage, ones, ones, floor)
    logger.debug("eliminate: %d points, %d halo, %d fixed, %d gone", n, nh, nf, len(gon))
    copy = np.zeros(len(allp), dtype=bool)
    copy[src[grid.copy]] = True
    left = np.isnan(prio[n : n + nh]) & ~copy[n : n + nh]
    out = prio[:n]
    out[np.isnan(out)] = np.inf  # exact copies
    return out, grid, left, rep


_OPTIONS = {"fixed", "alpha", "coverage"}


def eliminate(points, count=None, *, ratio=None, r_max=None, relocate_steps: int = RELOCATE_STEPS,
              threads: int | None = None, cell_points: int | None = CELL_POINTS, **options) -> np.ndarray:
    """Sorted int64 indices of exactly ``count`` (or round(ratio * n), at least 1) points of a whole cloud.

    The elimination (:func:`eliminate_order`) stops at the count, then
    ``relocate_steps`` restricted Lloyd steps (:func:`relocate`) lower the
    squared error. ``options``: ``fixed``, ``alpha``, ``coverage`` as in
    :func:`eliminate_order`.

    Above ``cell_points`` points (None: never), the cloud is split into
    cells of at most that many points, eliminated colour by colour on
    ``threads`` threads with their halos, as the out-of-core run does
    (:mod:`.eliminate_cells`); the kept set then differs from one
    elimination's, by as little as the engine's does. Only with the default
    key: with any of ``options`` set (fixed points belong to no cell, the
    cells run the default key), one elimination over the whole cloud. The result does not depend on ``threads``, nor on the input
    order up to ``.radius.AREA_SAMPLE`` points (above, r_max is solved on a seeded
    sample of rows).

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).random((1000, 3)) * [1, 1, 0.01]
    >>> len(eliminate(pts, ratio=0.2))
    200
    """
    pts = check_points(points)
    target = _target(len(pts), ratio, count)
    bad = set(options) - _OPTIONS
    if bad:
        raise InvalidParameterError(f"eliminate() got unexpected options {sorted(bad)}; halo and floor belong to "
                                    "eliminate_order (cells)")
    if int(relocate_steps) != relocate_steps or relocate_steps < 0:
        raise InvalidParameterError(f"relocate_steps must be an integer >= 0, got {relocate_steps!r}")
    if cell_points is not None and not (isinstance(cell_points, (int, np.integer)) and cell_points >= MIN_CELL_POINTS):
        raise InvalidParameterError(f"cell_points must be None or an integer >= {MIN_CELL_POINTS}, got "
                                    f"{cell_points!r}")
    r_max = None if r_max is None else check_r_max(r_max)
    if cell_points is not None and not options and 0 < target < len(pts):
        from .eliminate_cells import cell_cap, eliminate_in_cells

        cap = cell_cap(len(pts), target, int(cell_points))
        if len(pts) > cap:  # more than one cell
            workers = numba.get_num_threads() if threads is None else max(1, int(threads))
            keep, r_max = eliminate_in_cells(pts, target, r_max, cap, int(relocate_steps), workers)
            if keep is not None:
                return np.flatnonzero(keep).astype(np.int64)
    r_max = area_radius(pts, np.zeros((0, 3)), target) if r_max is None else r_max
    opts = {"fixed": None, "alpha": ALPHA, "coverage": True} | options
    prio, grid, _, rep = _eliminate_order(pts, r_max, None, None, None, opts["fixed"], opts["alpha"],
                                          opts["coverage"], target, threads)
    keep = keep_lowest(prio, target)
    if opts["fixed"] is not None:  # the grid holds the fixed points too: relocation runs without them
        grid = None
    if relocate_steps and math.isfinite(r_max) and target:
        with numba_threads(threads):
            keep = relocate_points(pts, keep, np.zeros((0, 3)), np.zeros(0, dtype=bool), r_max, int(relocate_steps),
                                   grid, None if grid is None else rep)
    return np.flatnonzero(keep).astype(np.int64)
