"""The ``eliminate`` rule at small kept shares: weighted sample elimination in stages.

Eliminating n points to N, each neighbour list holds about 3.6 n / N points and a
cell (:func:`.eliminate_cells.cell_cap`) about 1,024 n / N, so a cell's lists grow
as (n / N)^2: at small shares, gigabytes.

Keeping fewer than 1 in :data:`STAGED_BELOW` of its distinct points, an elimination
runs in stages (as Yuksel's progressive sampling): S = ceil(log2(n / (16 N)))
stages each keep the share s = (16 N / n)^(1/S) of the points left, stage t at
radius r_max sqrt(N / (n s^t)), down to about 16 N points (:data:`LAST_STAGE`);
the last stage keeps N of them at r_max, with relocation. Lists then hold <= 7.2
entries a point, as at 50% kept. Stopping at 16 N, not 2 N: halving an evenly
spread set leaves holes.

The engine decides once per run from its count and distinct points. A cell
(:func:`.eliminate_cells.eliminate_cell`) stages its points with its free halo
points; fixed points weigh in every stage, gone points in the first only.
"""

from __future__ import annotations

import math

import numpy as np

from .duplicates import copy_rows

__all__ = ["STAGED_BELOW", "LAST_STAGE", "small_share", "runs_staged", "stage_plan", "eliminate_staged"]

#: an elimination keeping fewer than 1 in this many of its distinct points (rounded down) runs in
#: stages; below 1 in 20 one elimination's memory grows fast
STAGED_BELOW = 20
#: the stages thin the points to this many times the count; the last stage keeps 1 in this many
LAST_STAGE = 16


def small_share(count: int, distinct: int) -> bool:
    """Whether keeping *count* of *distinct* points runs in stages: fewer than distinct // :data:`STAGED_BELOW` (ratio 0.05 never does)."""
    return count < distinct // STAGED_BELOW


def runs_staged(pts: np.ndarray, count: int) -> bool:
    """Whether eliminating valid *pts* to *count* (0 < count < n) runs in stages: :func:`small_share` of the distinct points."""
    n = len(pts)
    return small_share(count, n) and small_share(count, n - int(copy_rows(pts).sum()))


def stage_plan(n: int, count: int) -> tuple[int, float]:
    """The stages S = ceil(log2(n / (16 count))) before the last (0 < 16 count < n) and the share s = (16 count / n)^(1/S) each keeps."""
    left = LAST_STAGE * count
    stages = max(1, math.ceil(math.log2(n / left)))
    return stages, (left / n) ** (1.0 / stages)


def eliminate_staged(direct, pts: np.ndarray, count: int, r_max: float, hal: np.ndarray, kind: np.ndarray,
                     steps: int, threads, cell_points) -> np.ndarray:
    """Keep mask (n,) of exactly *count* points of valid *pts* (0 < 16 count < n, r_max finite), by stages.

    Halo *hal* (h, 3) of kinds *kind* (h,) uint8 as :func:`.eliminate_cells.eliminate_cell`;
    *steps* relocation steps in the last stage; each stage over cells of *cell_points*
    (None: one elimination). *direct* is :func:`.eliminate_cells.eliminate_direct`
    (passed in: that module calls this one).
    """
    n = len(pts)
    stages, share = stage_plan(n, count)
    own = np.arange(n)  # the cell's points left, and the free halo points left
    free = np.flatnonzero(kind == 1)
    fixed = hal[kind == 2]
    gone = hal[kind == 0]
    for t in range(1, stages + 1):
        points = np.concatenate([pts[own], hal[free]])
        outer = np.concatenate([fixed, gone]) if t == 1 else fixed
        kept = np.r_[np.ones(len(fixed), dtype=bool), np.zeros(len(outer) - len(fixed), dtype=bool)]
        target = min(max(1, round(len(points) * share)), len(points))
        keep = direct(points, target, r_max * math.sqrt(count / (n * share**t)), outer,
                      np.where(kept, 2, 0).astype(np.uint8), 0, threads, cell_points)
        left = own[keep[: len(own)]]
        if len(left) < count:  # the halo's points took the place of the cell's: the last stage from the stage before
            break
        own, free = left, free[keep[len(own) :]]
    outer = np.concatenate([fixed, hal[free]])
    okind = np.r_[np.full(len(fixed), 2), np.ones(len(free))].astype(np.uint8)
    keep = np.zeros(n, dtype=bool)
    keep[own[direct(pts[own], count, r_max, outer, okind, steps, threads, cell_points)]] = True
    return keep
