"""How many points each cell keeps: the sizes of greedy packings, a cheap rehearsal of the elimination.

The ``eliminate`` rule runs cell by cell, each to its own count, so counts must
say where one elimination over the whole cloud would keep its points. The k-NN
area model (:mod:`.radius`) ignores how points are arranged (scan lines, strips,
piles). A greedy packing at radius rho (each point joins unless one already in is
closer than rho) is a Poisson-disk subset too, so its size follows the
arrangement as the elimination's does (README, "eliminate in cells").

:func:`packing_ladder` measures a cell's packings at radii ``LADDER`` x r_max;
:func:`ladder_shares` finds the radius where all cells' packings total the target;
:func:`kept_counts` makes exact integer counts.
"""

from __future__ import annotations


import numpy as np

from .cellgrid import CellGrid
from .kernels import packing as _kp

__all__ = ["LADDER", "packing_ladder", "ladder_shares", "kept_counts"]

#: packing radii in r_max, around where the packings total the target
LADDER = (0.84, 1.0, 1.19, 1.41, 1.68, 2.0)


def packing_ladder(points: np.ndarray, r_max: float) -> tuple[np.ndarray, int]:
    """Greedy packing sizes of valid *points* (n, 3) at radii ``LADDER`` x finite *r_max*, and the distinct count.

    Copies join no packing; the grid's canonical order makes it independent of input order and threads.
    """
    n = len(points)
    if n == 0:
        return np.zeros(len(LADDER), dtype=np.int64), 0
    rad = np.array(LADDER) * float(r_max)
    grid = CellGrid(points, float(rad[-1]))
    counts = _kp.packing_counts(*grid.args(), grid.copy, rad * rad)
    return counts, int(n - grid.copy.sum())


def ladder_shares(counts, target: int) -> np.ndarray:
    """Expected kept points (P,) of cells with packing sizes *counts* (P, L): sizes where they total *target* (linear between rungs)."""
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

    *expected* (P,) scaled to the target, clipped to each cell's *distinct* points (the
    excess spread proportionally), rounded by largest remainder (ties by cell id).
    Copies never count. Returns q_j in [0, distinct_j], int64 (P,).

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
