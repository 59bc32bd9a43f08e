"""Input checks of the in-memory method, and the k formula.

Public functions of :mod:`cloudsieve.core` validate arrays here once (options:
:mod:`cloudsieve.params`); kernels assume valid input.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidParameterError, InvalidPointsError

__all__ = [
    "neighbour_count",
    "ratio_count",
    "check_points",
    "check_labels",
    "check_context",
]


def neighbour_count(m, k0: float = 1.0, k_min: int = 4):
    """k = max(k_min, floor(k0 * sqrt(m) + 1/2)) for clusters of m points (array-friendly).

    Returns an int64 ndarray of the shape of ``m``.
    """
    m = np.asarray(m)
    k = np.floor(k0 * np.sqrt(m) + 0.5).astype(np.int64)
    return np.maximum(k, int(k_min))


def ratio_count(ratio: float, n: int) -> int:
    """Points kept by share *ratio* of *n*: round(ratio * n), at least 1 when ratio > 0.

    >>> ratio_count(0.5, 5000), ratio_count(0.5, 1), ratio_count(0.0, 10)
    (2500, 1, 0)
    """
    k = int(round(float(ratio) * n))
    return max(k, 1) if ratio > 0 and n > 0 else k


def check_points(points, name: str = "points") -> np.ndarray:
    """Validated coordinates: shape (n, p), float64, C-contiguous, finite.

    ``points`` itself when already so, else a copy; ``name`` is used in messages.

    Raises
    ------
    InvalidParameterError
        Wrong shape or dtype.
    InvalidPointsError
        A NaN or infinite coordinate.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 1:
        raise InvalidParameterError(f"{name} must have shape (n, d), got shape {pts.shape}")
    if not np.issubdtype(pts.dtype, np.number) or np.iscomplexobj(pts):
        raise InvalidParameterError(f"{name} must be real numbers, got dtype {pts.dtype}")
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        total = np.add.reduce(pts, axis=None)
    if np.isfinite(total):  # NaN and inf carry through a sum: every coordinate finite (a tenth of the rows'
        return pts  # test; a sum that overflows tests the rows)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InvalidPointsError(
            f"{name} has {int(bad.sum())} non-finite (NaN or infinite) rows, the first at index {first}: {pts[first].tolist()}"
        )
    return pts


def check_labels(labels, n: int) -> np.ndarray:
    """Cluster labels as ndarray of shape (n,), int64 (None: one cluster, all zeros)."""
    if labels is None:
        return np.zeros(n, dtype=np.int64)
    lab = np.asarray(labels)
    if lab.shape != (n,):
        raise InvalidParameterError(f"labels must have shape ({n},) like the points, got shape {lab.shape}")
    if n and not np.issubdtype(lab.dtype, np.integer):
        raise InvalidParameterError(f"labels must be integers, got dtype {lab.dtype}")
    return lab.astype(np.int64, copy=False)


def check_context(context, p: int) -> np.ndarray | None:
    """Validated density context of shape (q, p) like the points' p columns, or None."""
    if context is None:
        return None
    ctx = check_points(context, "context")
    if ctx.shape[1] != p:
        raise InvalidParameterError(f"context must have {p} columns like the points, got shape {ctx.shape}")
    return ctx
