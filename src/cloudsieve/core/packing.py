"""How many points each cell keeps: the sizes of greedy packings, a cheap rehearsal of the elimination.

The ``eliminate`` rule runs cell by cell (out of core, and in memory above
``cell_points``), each cell to its own count q_j, so the counts must say
where the elimination over the whole cloud would keep its points. The k-NN
area model (:mod:`.radius`) misplaces them: on the shared scans, cells of
16,384 points got counts 11-41% off the whole cloud's elimination on
average (pumpAVisualReferenceImage.e57 at 50%, append-bug at 10%), because
its areas ignore how the points are arranged (scan lines, strips, piles),
and the cells' kept sets had 2-83% more point RMS than one elimination and
opened holes (point max up to 11x).

A greedy packing at radius rho (points in a fixed order; each joins unless
a point already in is closer than rho) is also a Poisson-disk subset, so
its size follows the arrangement as the elimination's does: with rho solved
so that the cloud's packings total the target, the cells' packing sizes
were within 1-5% of the elimination's kept points per cell, and the
cells' kept sets had the point RMS of one elimination over the whole cloud
to 1% (README, "eliminate in cells").

:func:`packing_ladder` measures one cell's packings at radii ``LADDER`` x
r_max in one pass; :func:`ladder_shares` finds, for all cells together, the
radius at which the packings total the target (linear between two rungs)
and returns each cell's packing size there: the expected kept points that
:func:`kept_counts` turns into exact integer counts.
"""

from __future__ import annotations


import numpy as np

from .cellgrid import CellGrid
from .kernels import packing as _kp

__all__ = ["LADDER", "packing_ladder", "ladder_shares", "kept_counts"]

#: packing radii in r_max: the radius at which the packings total the target was 1.06-1.46 r_max on the shared
#: scans at 50%, 20% and 10% kept
LADDER = (0.84, 1.0, 1.19, 1.41, 1.68, 2.0)


def packing_ladder(points: np.ndarray, r_max: float) -> tuple[np.ndarray, int]:
    """Greedy packing sizes of *points* (valid (n, 3)) at radii ``LADDER`` x *r_max* (finite), and the
    number of distinct points. Exact copies join no packing; the visiting order is the grid's canonical
    one (by cell, then coordinates), so neither the input order nor the thread count matters."""
    n = len(points)
    if n == 0:
        return np.zeros(len(LADDER), dtype=np.int64), 0
    rad = np.array(LADDER) * float(r_max)
    grid = CellGrid(points, float(rad[-1]))
    counts = _kp.packing_counts(*grid.args(), grid.copy, rad * rad)
    return counts, int(n - grid.copy.sum())


def ladder_shares(counts, target: int) -> np.ndarray:
    """Expected kept points (P,) of cells with packing sizes *counts* (P, L) along ``LADDER``: each cell's
    size at the radius where the sizes total *target* (linear between the two rungs around it; the end
    rung's sizes beyond the ladder)."""
    c = np.asarray(counts, dtype=np.float64).reshape(-1, len(LADDER))
    total = c.sum(axis=0)  # non-increasing along the ladder
    if not len(c) or target >= total[0]:
        return c[:, 0].copy()
    if target <= total[-1]:
        return c[:, -1].copy()
    k = int(np.flatnonzero(total >= target)[-1])  # total[k] >= target > total[k + 1]
    t = (total[k] - target) / (total[k] - total[k + 1])
    return c[:, k] + t * (c[:, k + 1] - c[:, k])


def kept_counts(expected, distinct, target: int) -> np.ndarray:
    """Integer kept counts of the cells summing exactly to *target* (all distinct points when fewer).

    The shares *expected* scaled to the target, each clipped to its cell's
    *distinct* points (the excess spread over the others, again in
    proportion), then rounded by largest remainder (ties by cell id). Exact
    copies never count: a target above the distinct points is not met (the
    run says so). Deterministic.

    Parameters
    ----------
    expected : array_like of shape (P,), float >= 0
    distinct : array_like of shape (P,), int
        Distinct points of each cell.
    target : int

    Returns
    -------
    ndarray of shape (P,), int64
        q_j in [0, distinct_j]; sum min(target, sum distinct).

    Examples
    --------
    >>> kept_counts([1.0, 1.0, 2.0], [5, 5, 5], 5).tolist()
    [1, 1, 3]
    """
    e = np.maximum(np.nan_to_num(np.asarray(expected, dtype=np.float64)), 0.0)
    cap = np.asarray(distinct, dtype=np.int64)
    goal = min(int(target), int(cap.sum()))
    x = np.zeros(len(cap))
    full = cap <= 0
    while goal > 0:  # at most P rounds: every round clips at least one more cell
        if full.all():
            x = cap.astype(np.float64)
            break
        w = np.where(full, 0.0, e)
        if not w.sum() > 0:
            w = np.where(full, 0.0, cap.astype(np.float64))
        x = np.where(full, cap, w * ((goal - cap[full].sum()) / w.sum()))
        over = ~full & (x >= cap)
        if not over.any():
            break
        full |= over
    q = np.minimum(np.floor(x).astype(np.int64), cap)
    order = np.lexsort((np.arange(len(cap)), -(x - q)))  # largest remainder, ties by cell id
    while q.sum() < goal:
        room = order[q[order] < cap[order]]
        q[room[: goal - int(q.sum())]] += 1
    while q.sum() > goal:  # rounding of the scaled shares only
        has = order[::-1][q[order[::-1]] > 0]
        q[has[: int(q.sum()) - goal]] -= 1
    return q  # exact copies never fill a count (the duplicates policy): the run says when it is missed
