"""The ``eliminate`` rule: weighted sample elimination, coverage first, information second.

Yuksel 2015 ("Sample Elimination for Generating Poisson Disk Sample Sets";
CGAL's ``poisson_eliminate``): every point gets a crowding weight from its
neighbours closer than 2 r_max, the heaviest point goes, its neighbours get
lighter, until the count is reached. Here the key of a point x is::

    key(x) = w(x) * f(x)
    w(x)   = sum over remaining y with d(x, y) < 2 r_max of (1 - d(x, y) / (2 r_max)) ** alpha
    f(x)   = g(e(x)) / (1 + lam * c(x) / r_max^2)

- w is Yuksel's crowding weight, with alpha = 1 (``ALPHA``; Yuksel and CGAL
  use 8; on the shared scans alpha = 1 gave lower point RMS and max errors at
  every ratio, e.g. bun_zipper at 20%: RMS 0.975x / max 1.04x the best
  baseline against 0.999x / 1.13x with alpha = 8);
- f is the coverage term: x represents itself and every removed point whose
  nearest remaining point it is; e(x) is the largest distance one of them
  would have to its nearest remaining point if x went, c(x) the sum of the
  squared distances they would gain; g(e) = 1 up to r_cov = 0.8 r_max, then
  (r_cov / e)^8; lam = 10. Plain WSE leaves holes (point max 1.35-1.86x the
  best of voxel/Poisson/farthest point on the shared scans); with f, 1.02-1.16x.

No information term (an entropy rank or a geometric importance multiplying
the key): neither lowers the errors at equal count (docs/architecture.md,
"Design reasons"); the compiled loop takes their per-point factors, all 1.

r_max: :mod:`.radius` (from the area of the sampled surface and the count). The elimination loop
on a grid, its constants and :func:`keep_lowest` are in :mod:`.elimination` (shared with
:mod:`.eliminate_cells`).

Priorities: each point gets its key when it was removed. Keys only decrease
as points go and the largest is always next, so priorities are
non-increasing along the removals, and the removal order is exactly
"priority descending, ties lower index first": keeping the N points of
lowest priority (:func:`keep_lowest`) is the elimination stopped at N.
The full order, with the kernels' other options (a halo, fixed and gone
points, a floor, any alpha, no coverage term), is the tests' reference
(tests/eliminate_oracle.py), which checks this elimination and the cells'.

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

import math

import numba
import numpy as np

from ..params import COMMANDS, validate_params
from ._validation import ratio_count
from .cellgrid import CellGrid, check_points
from .kernels import neighbours as _kn
from .elimination import ALPHA, alpha_int, area_radius, keep_lowest, run_elimination
from .relocate import RELOCATE_STEPS, check_r_max, numba_threads, relocate, relocate_points

__all__ = ["CELL_POINTS", "MIN_CELL_POINTS", "eliminate", "keep_lowest", "relocate"]

#: eliminate() runs over cells of at most this many points above it (module .eliminate_cells): a third of the
#: time of one elimination at 1 M points. Smaller cells fit the caches better, but the halos and calls grow;
#: larger ones leave the caches
CELL_POINTS = 16_384
#: the smallest cell_points accepted (the option's, :mod:`cloudsieve.params_spec`): below it the halos outweigh the
#: cells
MIN_CELL_POINTS = int(COMMANDS["eliminate"]["cell_points"].low)


def _eliminated(pts: np.ndarray, r_max: float, target: int, threads) -> tuple:
    """One elimination of *pts* (valid) stopped at *target* points: the keep mask, the grid and each grid row's
    nearest point left (module .kernels.cover), both None when no elimination ran (no points, r_max inf)."""
    n = len(pts)
    if not n or not math.isfinite(r_max):  # every point is kept: nobody weighs on anybody; copies go first
        prio = np.zeros(n)
        if n:
            grid = CellGrid(pts, 0.0)
            prio[grid.order[grid.copy]] = np.inf
        return keep_lowest(prio, target), None, None
    two_r = 2.0 * r_max
    with numba_threads(threads):
        grid = CellGrid(pts, two_r)
        state = np.ones(n, dtype=np.uint8)
        state[grid.copy] = 0
        ones = np.ones(n)  # the key's factors of the removed information terms (module docstring)
        lists = _kn.build_lists(*grid.args(), grid.order, state, two_r, ALPHA, alpha_int(ALPHA), True)
        prio, rep = run_elimination(grid, lists, state, n, np.full(n, -1, dtype=np.int64), r_max, ALPHA, True,
                                    ones, ones, target, False)  # the keys of the points left: not needed
    prio[np.isnan(prio)] = np.inf  # exact copies
    return keep_lowest(prio, target), grid, rep


@validate_params("eliminate")
def eliminate(points, count=None, *, ratio=None, r_max=None, relocate_steps: int = RELOCATE_STEPS,
              threads: int | None = None, cell_points: int | None = CELL_POINTS) -> np.ndarray:
    """Sorted int64 indices of exactly ``count`` (or round(ratio * n), at least 1) points of a whole cloud.

    The options are validated once (:func:`cloudsieve.params.validate`, command ``eliminate``): one of
    ``ratio`` in (0, 1] and ``count`` >= 1 (a count above the points keeps them all), ``relocate_steps`` >= 0,
    ``threads`` >= 1, ``cell_points`` None or >= ``MIN_CELL_POINTS``; ``r_max`` (a radius: inf keeps all) is
    checked here. ``eliminate.unchecked`` takes validated options and also a count of 0 (nothing kept).

    The elimination (module docstring, alpha = 1 with the coverage term)
    stops at the count, then ``relocate_steps`` restricted Lloyd steps
    (:func:`relocate`) lower the squared error.

    Above ``cell_points`` points (None: never), the cloud is split into
    cells of at most that many points, eliminated colour by colour on
    ``threads`` threads with their halos, as the out-of-core run does
    (:mod:`.eliminate_cells`); the kept set then differs from one
    elimination's, by as little as the engine's does. Below 1 in
    :data:`.staged.STAGED_BELOW` of the distinct points kept, the
    elimination runs in stages of about half (:mod:`.staged`), each over
    cells as above. The result does not
    depend on ``threads``, nor on the input order up to
    ``.radius.AREA_SAMPLE`` points (above, r_max is solved on a seeded sample
    of rows).

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).random((1000, 3)) * [1, 1, 0.01]
    >>> len(eliminate(pts, ratio=0.2))
    200
    """
    pts = check_points(points)
    target = ratio_count(ratio, len(pts)) if ratio is not None else min(int(count), len(pts))
    r_max = None if r_max is None else check_r_max(r_max)
    if 0 < target < len(pts):
        from .eliminate_cells import eliminate_direct
        from .staged import eliminate_staged, runs_staged

        if runs_staged(pts, target):  # a small share kept: stages of about half (module .staged)
            r_max = area_radius(pts, np.zeros((0, 3)), target) if r_max is None else r_max
            if math.isfinite(r_max):
                workers = numba.get_num_threads() if threads is None else max(1, int(threads))
                keep = eliminate_staged(eliminate_direct, pts, target, r_max, np.zeros((0, 3)),
                                        np.zeros(0, dtype=np.uint8), int(relocate_steps), workers, cell_points)
                return np.flatnonzero(keep).astype(np.int64)
    if cell_points is not None and 0 < target < len(pts):
        from .eliminate_cells import cell_cap, eliminate_in_cells

        cap = cell_cap(len(pts), target, int(cell_points))
        if len(pts) > cap:  # more than one cell
            workers = numba.get_num_threads() if threads is None else max(1, int(threads))
            keep, r_max = eliminate_in_cells(pts, target, r_max, cap, int(relocate_steps), workers)
            if keep is not None:
                return np.flatnonzero(keep).astype(np.int64)
    r_max = area_radius(pts, np.zeros((0, 3)), target) if r_max is None else r_max
    keep, grid, rep = _eliminated(pts, r_max, target, threads)
    if relocate_steps and math.isfinite(r_max) and target:
        with numba_threads(threads):
            keep = relocate_points(pts, keep, np.zeros((0, 3)), np.zeros(0, dtype=bool), r_max, int(relocate_steps),
                                   grid, rep)
    return np.flatnonzero(keep).astype(np.int64)
