"""The uniform grid the ``eliminate`` rule searches, and its input checks.

:class:`CellGrid` puts points in the canonical internal order of the compiled
kernels (:mod:`.kernels.grid`): by grid cell along a Z-order curve (nearby
cells nearby in memory), inside a cell by coordinates, exact copies by their
position. The order depends on the coordinates only, not on the input order,
so sums over neighbours come out bit for bit the same for any permutation of
the points.
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
    """Contiguous float64 array of shape (n, 3), or InvalidParameterError/InvalidPointsError.

    The core's point check (:func:`._validation.check_points`) plus the 3 columns the grid needs.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidParameterError(f"{name} must have shape (n, 3), got shape {pts.shape}")
    return core_check_points(pts, name)


class CellGrid:
    """Points sorted into cubic cells of side >= ``h`` (the widest search radius).

    Parameters
    ----------
    points : ndarray of shape (n, 3), float64, finite (not checked)
    h : float > 0
        Cell side; raised so that no axis has 2^21 cells or more.

    Attributes
    ----------
    order : ndarray of shape (n,), int64
        Row i of the internal order is ``points[order[i]]``.
    P : ndarray of shape (n, 3)
        The points in internal order.
    cell, cstart, nstart, ncells : ndarray of int64
        Cell of each row, first row of each cell, and the CSR list of the
        occupied cells among the 27 around each cell.
    copy : ndarray of shape (n,), bool
        Rows equal to the previous row (exact copies; the first of each group is not a copy).
    lead : ndarray of shape (n,), int64
        The first row of each row's group of exact copies (the row itself when it is no copy).
    h : float
        The cell side used.
    lo : ndarray of shape (3,)
        The grid's corner: the points' minimum.
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
        """:func:`.kernels.grid.nearest_kept` of ascending ``rows``, searched once per group of exact copies.

        The rows of a group have the same coordinates and so the same answer
        (the search excludes no row); searched row by row, a pile of m copies
        in one grid cell costs m^2 distances (autzen_trim holds piles of
        thousands). kept (n,) uint8.
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
