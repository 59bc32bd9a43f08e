"""The ``eliminate`` rule at small kept shares: weighted sample elimination in stages.

An elimination of n points to N lists, for every point, its neighbours
closer than 2 r_max, and r_max^2 grows as the area per kept point, so a
point's list holds about 4 pi / (2 sqrt(3)) n / N = 3.6 n / N points, and
the cells (:func:`.eliminate_cells.cell_cap`: at least 1,024 kept points
each) hold 1,024 n / N points: the lists of a cell hold 3,700 (n / N)^2
entries. At 1 point of autzen_trim's 110,000 that is the whole cloud in
every list (an array of 6.2 GiB asked of numpy at 6.6 GB resident); at 1%
of a 519,000-point scan, 5.4 GB.

Keeping fewer than 1 in :data:`STAGED_BELOW` of its distinct points (their
number divided by 20, rounded down), an elimination runs in stages, as
Yuksel's progressive sampling (2015) makes nested sets, each stage at the
radius of its own count: S = ceil(log2(n / (16 N))) stages each keep the
share s = (16 N / n)^(1/S) (0.5 to 1) of the points left, stage t at the
radius r_max sqrt(N / (n s^t)), down to about 16 N points
(:data:`LAST_STAGE`); then the last stage keeps N of them at r_max, with
its relocation. Each stage is the rule's elimination (key, coverage term,
cells and colours) of the points the stage before kept. The stages' lists
hold about 3.6 / s <= 7.2 entries a point and their cells at most
:data:`~.eliminate.CELL_POINTS` points, as at 50% kept; the last stage's,
58 entries a point on cells of 16,384 points, less than at 5% kept. The
stages' points halve, so all of them cost about twice the first; the last
stage, on 16 N points, costs what an elimination of 16 N points to 1 in 16
does.

Down to 16 N points, not to 2 N: thinning a set that is already spread
evenly (a stage's output) to half leaves holes where thinning a denser one
to a sixteenth does not. Against one elimination, on bun_zipper and
maxplanck at 4.9%, 1% and 0.3% kept and autzen_trim at 4.9% and 1% (at
0.3% one elimination did not fit in 9 GB): point RMS error 1-6% higher,
point max 6% lower to 7% higher; with stages of half down to N, 3-18% and
6-22% higher; down to 20 N, 0-5% higher and 9% lower to 6% higher, the
last stage longer (519,000 points at 1%: 1.9-2.0 times the run at 50%
against 1.6-1.8 times).

The engine decides once for a run, from its count and its distinct points:
every cell of a run keeping 1 in 20 or more (any ``--ratio`` from 0.05 up)
runs one elimination, whatever its own share. A cell of a larger cloud
(:func:`.eliminate_cells.eliminate_cell`) runs its stages on its points and
its halo's free points (a higher colour's, eliminated along) as one set;
its fixed points (a lower colour's kept ones) weigh in every stage, its
gone points (a lower colour's removed ones) in the first only, where the
points around them have their density. The last stage eliminates the
cell's points left to its count, with the free points left as its halo,
eliminated along.
"""

from __future__ import annotations

import math

import numpy as np

from .duplicates import copy_rows

__all__ = ["STAGED_BELOW", "LAST_STAGE", "small_share", "runs_staged", "stage_plan", "eliminate_staged"]

#: an elimination keeping fewer than 1 in this many of its distinct points (their number divided by it, rounded
#: down) runs in stages; 1 in 20 and more, one elimination. At 5% kept one elimination (lists of about 72 entries a
#: point, cells of 20,480 points) peaks at 1.4 times the memory of one at 50% (autzen_trim in memory), at 3.2% at
#: 2.0-2.2 times (cells of 32,000, 115 entries a point)
STAGED_BELOW = 20
#: the stages thin the points down to this many times the count, the last stage keeps 1 in this many of them
LAST_STAGE = 16


def small_share(count: int, distinct: int) -> bool:
    """Whether keeping *count* of *distinct* points runs in stages: fewer than 1 in :data:`STAGED_BELOW` of
    them, rounded down, so that a ratio of 0.05 (``round(0.05 * n)`` points) never does (the engine asks it
    once for all the cells of a run)."""
    return count < distinct // STAGED_BELOW


def runs_staged(pts: np.ndarray, count: int) -> bool:
    """Whether an elimination of *pts* (valid) to *count* (0 < count < n) runs in stages: :func:`small_share`
    of the distinct points (exact copies are the first to go, whatever the count)."""
    n = len(pts)
    return small_share(count, n) and small_share(count, n - int(copy_rows(pts).sum()))


def stage_plan(n: int, count: int) -> tuple[int, float]:
    """The stages S = ceil(log2(n / (16 count))) before the last one of an elimination of *n* points to
    *count* (0 < 16 count < n, :data:`LAST_STAGE`), and the share s = (16 count / n)^(1/S) each keeps."""
    left = LAST_STAGE * count
    stages = max(1, math.ceil(math.log2(n / left)))
    return stages, (left / n) ** (1.0 / stages)


def eliminate_staged(direct, pts: np.ndarray, count: int, r_max: float, hal: np.ndarray, kind: np.ndarray,
                     steps: int, threads, cell_points) -> np.ndarray:
    """Keep mask (n,) of exactly *count* points of *pts* (valid; 0 < 16 count < n, r_max finite) by stages
    (module docstring), with the halo *hal* (h, 3) of kinds *kind* (h,) uint8 (1 free, 2 fixed, 0 gone:
    :func:`.eliminate_cells.eliminate_cell`), *steps* relocation steps in the last stage, on *threads*
    threads, each stage over cells of *cell_points* (None: one elimination a stage). *direct* is the one
    elimination of a stage, :func:`.eliminate_cells.eliminate_direct` (passed in: that module calls this
    one)."""
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
