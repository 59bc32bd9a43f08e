"""The uniform grid the ``eliminate`` rule searches.

:class:`CellGrid` orders points by cell along a Z-order curve, inside a cell by
coordinates, copies by position: the order depends on coordinates only, so
neighbour sums are bit-identical for any permutation of the input.
"""

from __future__ import annotations

import numpy as np

from ..chunk import take_rows, xyz_bounds
from ..errors import InvalidParameterError
from ._validation import check_points as core_check_points
from .kernels import grid as _kg

__all__ = ["CellGrid", "check_points"]

_RUN = 64  # longest run of one cell sorted by insertion; longer (piles of copies, dense spots): a lexsort each


def check_points(points, name: str = "points") -> np.ndarray:
    """Contiguous float64 (n, 3) array: :func:`._validation.check_points` plus 3 columns."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidParameterError(f"{name} must have shape (n, 3), got shape {pts.shape}")
    return core_check_points(pts, name)


class CellGrid:
    """Points (n, 3) float64, finite (not checked), sorted into cubic cells of side >= ``h`` (the widest search radius).

    The side is raised so that no axis has 2^21 cells or more.

    Attributes
    ----------
    order : ndarray (n,), int64
        Row i of the internal order is ``points[order[i]]``; ``P`` holds the points in that order.
    cell, cstart, nstart, ncells : ndarray of int64
        Cell of each row, first row of each cell, CSR of occupied cells among the 27 around each.
    copy, lead : ndarray (n,)
        Row equals the previous row (bool); first row of its group of copies (int64).
    h, lo : float, ndarray (3,)
        The cell side used and the points' minimum.
    """

    def __init__(self, points: np.ndarray, h: float):
        lo, hi = xyz_bounds(points) if len(points) else (np.zeros(3), np.zeros(3))
        span = float((hi - lo).max())
        h = max(float(h), span / (2.0**21 - 2), 1e-300)
        codes = _kg.cell_codes(points, lo, h)
        order = _kg.argsort_keys(codes)
        cell, cstart, ukeys = _kg.code_runs(codes, order)
        P = take_rows(points, order)
        _kg.sort_cells(P, cstart, order, _RUN)  # the runs of at most _RUN points; the longer ones here
        size = np.diff(cstart)
        for a, b in zip(cstart[:-1][size > _RUN].tolist(), cstart[1:][size > _RUN].tolist()):
            q = P[a:b]  # by index (the argsort is stable), then (stable) by coordinates
            by = np.lexsort((q[:, 2], q[:, 1], q[:, 0]))
            order[a:b], P[a:b] = order[a:b][by], q[by]
        self.order = order
        self.P = P
        self.cell = cell
        self.cstart = cstart
        self.nstart, self.ncells = _kg.cell_neighbours(ukeys)
        self.h = h
        self.lo = lo
        self.copy, self.lead = _kg.copy_runs(self.P, cell)

    def nearest_kept(self, kept: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """:func:`.kernels.grid.nearest_kept` of ascending ``rows``, once per group of copies.

        Copies share the answer; row by row, a pile of m copies would cost m^2 distances.
        """
        lead = self.lead[rows]
        first = np.ones(len(lead), dtype=bool)  # lead is non-decreasing along ascending rows
        first[1:] = lead[1:] != lead[:-1]
        if first.all():
            return _kg.nearest_kept(*self.args(), kept, self.order, rows)
        return _kg.nearest_kept(*self.args(), kept, self.order, lead[first])[np.cumsum(first) - 1]

    def args(self) -> tuple:
        """(P, cell, cstart, nstart, ncells): the grid arguments of every kernel."""
        return self.P, self.cell, self.cstart, self.nstart, self.ncells
