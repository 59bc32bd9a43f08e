"""The weighted sample elimination on a grid, shared by the whole-cloud and the cell eliminations.

:func:`run_elimination` runs :mod:`.kernels.eliminate` on a :class:`.cellgrid.CellGrid`
and its lists; :func:`keep_lowest` keeps the points removed last; :func:`area_radius`
is r_max (:mod:`.radius`). Key and constants: :mod:`.eliminate`.
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import numpy as np

from ..errors import InvalidParameterError
from .kernels import eliminate as _ke
from .kernels import neighbours as _kn
from .radius import AREA_K, AREA_SAMPLE, areas_of, radius_of

__all__ = ["ALPHA", "COVER_RADIUS", "COVER_GAMMA", "COVER_LAMBDA", "Terms", "alpha_int", "area_radius", "run_elimination",
           "keep_lowest"]

logger = logging.getLogger(__name__)

ALPHA = 1.0  # exponent of the crowding weight (Yuksel: 8; module docstring)
COVER_RADIUS = 0.8  # r_cov / r_max: beyond it the coverage factor falls
COVER_GAMMA = 8.0  # exponent of the coverage factor
COVER_LAMBDA = 10.0  # weight of the squared-error factor


class Terms(NamedTuple):
    """The weight's terms: crowding exponent, coverage factor on or off, per-row scale and squared importance (None: ones)."""

    alpha: float = ALPHA
    coverage: bool = True
    scale: np.ndarray | None = None
    imp2: np.ndarray | None = None


def area_radius(pts: np.ndarray, ctx: np.ndarray, target: int) -> float:
    """r_max for *target* of the points *pts* from the areas around them (*ctx*: context points; inf for 0)."""
    if target == 0:
        return math.inf  # nothing is kept: the order does not matter
    areas, weight = areas_of(pts, ctx, AREA_K, AREA_SAMPLE, 0)
    return radius_of(areas, target, weight)


def alpha_int(alpha: float) -> int:
    """*alpha* as the small integer exponent the kernels raise to by multiplications, else -1."""
    return int(alpha) if alpha == int(alpha) and alpha <= 64 else -1


def run_elimination(grid, lists, state, n, gone_rep, r_max, floor, terms: Terms = Terms(),
                    keys_left: bool = True) -> tuple:
    """The elimination on a grid and its neighbour lists (``state`` of the grid's rows), to *floor* points, with *terms*.

    Returns the priority of every grid position (NaN: not removed nor own; own points
    left: their keys at the stop, or -1.0 without ``keys_left``), and each row's rep at
    the stop (:mod:`.kernels.cover`; -1 for copies and unreached points; None without
    the coverage term).
    """
    two_r = 2.0 * r_max
    nptr, nbr, low, soff, w, term = lists
    src = grid.order
    alpha, coverage = terms.alpha, terms.coverage
    ones = np.ones(len(src)) if terms.scale is None or terms.imp2 is None else None
    scale = ones if terms.scale is None else terms.scale
    imp2 = ones if terms.imp2 is None else terms.imp2
    r_cov, lam = (COVER_RADIUS * r_max, COVER_LAMBDA) if coverage else (0.0, 0.0)
    links = np.full((len(src), 8), -1, dtype=_kn.index_type(len(src), nptr[-1]))
    prio, stats = _ke.eliminate(*grid.args(), nptr, nbr, low, term, soff, state, scale, imp2, w, src, two_r, alpha,
                                alpha_int(alpha), r_cov, COVER_GAMMA, lam, floor, n, links, gone_rep, keys_left)
    logger.debug("eliminate: pops %d, stale %d, coverage %d, searches %d", *stats)
    out = np.empty(len(src))
    out[src] = prio
    return out, (links[:, 2].astype(np.int64) if coverage else None)


def keep_lowest(priority, count: int) -> np.ndarray:
    """Keep mask (n,) bool of the ``count`` points removed last: lowest priority, ties higher index."""
    p = np.asarray(priority, dtype=np.float64)
    if p.ndim != 1 or np.isnan(p).any():
        raise InvalidParameterError(f"priority must have shape (n,) without NaN, got shape {p.shape}")
    n = len(p)  # count: in [0, n], from a validated option or the engine's kept_counts (not checked here)
    keep = np.zeros(n, dtype=bool)
    k = int(count)
    if k == 0:
        return keep
    # the k lowest are the minimum's when it occurs k times (np.partition is slow on such arrays)
    at_min = p == p.min()
    if np.count_nonzero(at_min) == k:
        return at_min
    v = np.partition(p, k - 1)[k - 1]  # the count-th lowest priority: below it all go in, at it the highest indices
    keep[p < v] = True
    tied = np.flatnonzero(p == v)
    keep[tied[len(tied) - (k - int(keep.sum())) :]] = True
    return keep
