"""The reference elimination of the tests: the priority of every point, with every option of the kernels.

``eliminate_order`` was :func:`cloudsieve.core.eliminate.eliminate_order` before it left src (no caller there):
one elimination over the points with a halo (eliminated along, given no priority), fixed points (weigh, never
removed), gone points (removed already, each represented by its nearest point), any ``alpha``, with or without
the coverage term, stopped at a ``floor``. The tests check against it what src runs: the brute force of
tests/test_core_eliminate.py checks it, and it checks :func:`cloudsieve.core.eliminate_cells.eliminate_cell`
(the engine's cell: halo decided as fixed and gone points) and :func:`cloudsieve.core.eliminate.eliminate`
(one elimination stopped at the count). It calls the same kernels (:mod:`cloudsieve.core.elimination`,
:mod:`cloudsieve.core.kernels.neighbours`) on the same grid (:class:`cloudsieve.core.cellgrid.CellGrid`).
"""

from __future__ import annotations

import math

import numpy as np

from cloudsieve.core._validation import ratio_count
from cloudsieve.core.cellgrid import CellGrid, check_points
from cloudsieve.core.elimination import ALPHA, Terms, alpha_int, area_radius, run_elimination
from cloudsieve.core.kernels import neighbours as kn
from cloudsieve.core.relocate import check_r_max, numba_threads
from cloudsieve.errors import InvalidParameterError


def _target(n: int, ratio, count) -> int:
    if ratio is not None and count is not None:
        raise InvalidParameterError(f"give ratio or count, not both (ratio={ratio!r}, count={count!r})")
    if ratio is not None:
        return ratio_count(ratio, n)
    if count is None:
        raise InvalidParameterError("the eliminate rule needs a ratio or a count (or r_max)")
    return int(count)


def eliminate_order(points, *, r_max=None, ratio=None, count=None, halo=None, fixed=None, gone=None,
                    alpha: float = ALPHA, coverage: bool = True, floor: int = 0, threads: int | None = None,
                    halo_left: bool = False):
    """Priority of every point in the elimination order (larger goes first).

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    r_max : float, optional
        The Poisson-disk radius; inf: every point is kept (all priorities 0). Default: from the areas of
        ``points`` (halo as context) and the count of ``ratio``/``count``.
    ratio, count : optional
        The kept share in (0, 1] or count (one of them): for r_max only.
    halo : array_like of shape (h, 3), optional
        Points of the neighbouring cells: eliminated with the points but given no priority.
    fixed : array_like of shape (f, 3), optional
        Points that weigh on the others and are never removed.
    gone : array_like of shape (g, 3), optional
        Points already removed: they do not weigh, but each is represented from the start by its nearest
        point (of ``points``, ``halo``, ``fixed``; within 2 r_max), as if it had just gone. Exact copies of a
        point are not.
    alpha : float
        Exponent of the crowding weight, > 0.
    coverage : bool
        Use the coverage term; False: plain WSE.
    floor : int
        Stop when this many of the points are left (the halo's points do not count); the points left get
        their keys at the stop. 0: a full order.
    threads : int, optional
    halo_left : bool
        Also return which halo points are left at the stop.

    Returns
    -------
    ndarray of shape (n,), float64
        Key at removal: +inf for exact copies of a lower-index point. Removal order: priority descending,
        ties lower index first.
    left : ndarray of shape (h,), bool
        Only with ``halo_left``.
    """
    pts = check_points(points)
    n = len(pts)
    hal = np.zeros((0, 3)) if halo is None else check_points(halo, "halo")
    fix = np.zeros((0, 3)) if fixed is None else check_points(fixed, "fixed")
    gon = np.zeros((0, 3)) if gone is None else check_points(gone, "gone")
    r_max = area_radius(pts, hal, _target(n, ratio, count)) if r_max is None else check_r_max(r_max)
    if n == 0:
        out, left = np.zeros(0), np.ones(len(hal), dtype=bool)
    else:
        with numba_threads(threads):
            out, left = _order(pts, hal, fix, gon, r_max, float(alpha), bool(coverage), int(floor))
    return (out, left) if halo_left else out


def _order(pts, hal, fix, gon, r_max, alpha, coverage, floor) -> tuple:
    n, nh, nf = len(pts), len(hal), len(fix)
    if not math.isfinite(r_max):  # every point is kept: nobody weighs on anybody
        allp = np.concatenate([pts, hal, fix]) if nh or nf else pts
        grid = CellGrid(allp, 0.0)
        out = np.zeros(len(allp))
        out[grid.order[grid.copy]] = np.inf
        return out[:n], np.isfinite(out[n : n + nh]) if nh else np.ones(0, dtype=bool)
    allp = np.concatenate([pts, hal, fix, gon]) if nh or nf or len(gon) else pts
    two_r = 2.0 * r_max
    grid = CellGrid(allp, two_r)
    src = grid.order  # internal row -> position in allp
    state = np.where(src < n + nh, 1, np.where(src < n + nh + nf, 2, 0)).astype(np.uint8)
    state[grid.copy] = 0
    gone_rep = np.full(len(allp), -1, dtype=np.int64)
    if len(gon) and coverage:  # the gone points: represented by their nearest alive point (not their copies)
        rows = np.flatnonzero((src >= n + nh + nf) & ~grid.copy)
        gone_rep[rows] = grid.nearest_kept((state != 0).astype(np.uint8), rows)
    lists = kn.build_lists(*grid.args(), grid.order, state, two_r, alpha, alpha_int(alpha), coverage)
    prio, _ = run_elimination(grid, lists, state, n, gone_rep, r_max, floor, Terms(alpha, coverage))
    copy = np.zeros(len(allp), dtype=bool)
    copy[src[grid.copy]] = True
    left = np.isnan(prio[n : n + nh]) & ~copy[n : n + nh]
    out = prio[:n]
    out[np.isnan(out)] = np.inf  # exact copies
    return out, left
