"""The ``eliminate`` rule: weighted sample elimination, coverage first, information second.

Yuksel 2015 (CGAL's ``poisson_eliminate``): the heaviest point goes, its
neighbours get lighter, until the count is reached. The key of x::

    key(x) = w(x) * f(x)
    w(x)   = sum over remaining y with d(x, y) < 2 r_max of (1 - d(x, y) / (2 r_max)) ** alpha
    f(x)   = g(e(x)) / (1 + lam * c(x) / r_max^2)

- w: Yuksel's crowding weight with alpha = 1 (``ALPHA``; lower errors than 8 on the shared scans);
- f: coverage: e(x) is the largest distance a point x represents would have to
  its nearest remaining point if x went, c(x) the sum of squared distances they
  would gain; g(e) = 1 up to r_cov = 0.8 r_max, then (r_cov / e)^8; lam = 10.
  Without f, WSE leaves holes.

No information term (docs/architecture.md). r_max: :mod:`.radius`; the loop,
constants and :func:`keep_lowest`: :mod:`.elimination`. Keys only decrease, so
keeping the N lowest priorities is the elimination stopped at N (reference:
tests/eliminate_oracle.py); :func:`.relocate.relocate` follows. Exact duplicates
get priority +inf. The result depends on neither input order nor thread count.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..params import COMMANDS, validate_params
from ._validation import ratio_count
from .cellgrid import check_points
from .elimination import area_radius, keep_lowest
from .relocate import RELOCATE_STEPS, check_r_max, relocate

__all__ = ["CELL_POINTS", "MIN_CELL_POINTS", "eliminate", "keep_lowest", "relocate"]

#: eliminate() runs over cells of at most this many points above it (module .eliminate_cells)
CELL_POINTS = 16_384
#: the smallest cell_points accepted (:mod:`cloudsieve.params_spec`): below it halos outweigh cells
MIN_CELL_POINTS = int(COMMANDS["eliminate"]["cell_points"].low)


@validate_params("eliminate")
def eliminate(points, count=None, *, ratio=None, r_max=None, relocate_steps: int = RELOCATE_STEPS,
              threads: int | None = None, cell_points: int | None = CELL_POINTS) -> np.ndarray:
    """Sorted int64 indices of exactly ``count`` (or round(ratio * n), at least 1) points of a whole cloud.

    Options are validated once (:func:`cloudsieve.params.validate`, command ``eliminate``);
    ``r_max`` (inf keeps all) is checked here. ``eliminate.unchecked`` takes validated
    options and also a count of 0.

    The elimination stops at the count, then ``relocate_steps`` steps of
    :func:`relocate`. Above ``cell_points`` points (None: never) it runs over cells
    as :func:`.eliminate_cells.eliminate_cell`; below 1 in :data:`.staged.STAGED_BELOW`
    of the distinct points kept, in stages (:mod:`.staged`). Independent of
    ``threads``, and of input order up to ``.radius.AREA_SAMPLE`` points.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).random((1000, 3)) * [1, 1, 0.01]
    >>> len(eliminate(pts, ratio=0.2))
    200
    """
    from .eliminate_cells import eliminate_cell

    pts = check_points(points)
    target = ratio_count(ratio, len(pts)) if ratio is not None else min(int(count), len(pts))
    r_max = None if r_max is None else check_r_max(r_max)
    if 0 < target < len(pts):
        r_max = area_radius(pts, np.zeros((0, 3)), target) if r_max is None else r_max
    workers = numba.get_num_threads() if threads is None else max(1, int(threads))
    keep = eliminate_cell(pts, target, math.inf if r_max is None else r_max, steps=int(relocate_steps),
                          threads=workers, cell_points=cell_points)
    return np.flatnonzero(keep).astype(np.int64)
