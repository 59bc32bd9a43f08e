"""Exact duplicate points (same x, y, z): the one policy of every rule (DESIGN.md stages 4-5).

An exact copy of an earlier point (lower input index) carries no information:
it is scored once (only the first of its group is a point of the rules) and
kept at most once. Every rule runs on the distinct points; the copies go,
unless the user asks to keep them (``keep_duplicates``: every copy of a kept
point is kept too). Their count is reported by the engine's summary.

- :func:`exact_copies`: which points are copies of an earlier one, and
  :func:`first_copies`: the first point equal to each point (public,
  validate; a hash table over the rows, :mod:`.kernels.copies`);
- :func:`sorted_copies`: the same on rows already in canonical
  (lexicographic, stable) order, where copies are adjacent (a kernel, no
  checks), and :func:`first_rows` / :func:`copy_rows`: :func:`first_copies`
  / :func:`exact_copies` on valid points (no checks).
"""

from __future__ import annotations

import numpy as np

from ._validation import check_points
from .kernels import copies as _kc

__all__ = ["copy_rows", "exact_copies", "first_copies", "first_rows", "sorted_copies"]


def sorted_copies(P: np.ndarray) -> np.ndarray:
    """Rows equal to the row before them, in canonically ordered points (input assumed valid).

    Parameters
    ----------
    P : ndarray of shape (n, p), float64
        Rows in lexicographic order, ties in input order (:func:`.knn.canonical_order`).

    Returns
    -------
    ndarray of shape (n,), bool
        True for every row but the first of each group of equal rows.
    """
    copy = np.zeros(len(P), dtype=bool)
    if len(P) > 1:
        copy[1:] = (P[1:] == P[:-1]).all(axis=1)
    return copy


def exact_copies(points) -> np.ndarray:
    """Which points are exact copies of a point of lower index.

    Parameters
    ----------
    points : array_like of shape (n, p), float

    Returns
    -------
    ndarray of shape (n,), bool
        True for every copy; the first (lowest index) of each group of equal
        points is False, so ``points[~copies]`` holds each distinct point once.

    Examples
    --------
    >>> exact_copies([[0, 0, 0], [1, 0, 0], [0, 0, 0]]).tolist()
    [False, False, True]
    """
    return copy_rows(check_points(points))


def first_copies(points) -> np.ndarray:
    """The index of the first (lowest index) point equal to each point.

    Parameters
    ----------
    points : array_like of shape (n, p), float

    Returns
    -------
    ndarray of shape (n,), int64
        ``first[i] == i`` for a point that is no copy; ``keep[first]`` makes
        every copy follow its first point.

    Examples
    --------
    >>> first_copies([[0, 0, 0], [1, 0, 0], [0, 0, 0]]).tolist()
    [0, 1, 0]
    """
    return first_rows(check_points(points))


def first_rows(pts: np.ndarray) -> np.ndarray:
    """:func:`first_copies` of valid points: a hash table over the rows' bits (-0.0 as +0.0)."""
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    return _kc.first_equal((pts + 0.0).view(np.uint64))


def copy_rows(pts: np.ndarray) -> np.ndarray:
    """:func:`exact_copies` of valid points (rows of float64, any number of columns)."""
    first = first_rows(pts)
    return first != np.arange(len(first))
