"""Exact duplicate points (same x, y, z): one policy for every rule (DESIGN.md stages 4-5).

A copy of a lower-index point is scored and kept at most once: rules run on
distinct points; copies go unless ``keep_duplicates`` keeps every copy of a kept point.
:func:`exact_copies` and :func:`first_copies` validate; :func:`sorted_copies`,
:func:`first_rows` and :func:`copy_rows` do not.
"""

from __future__ import annotations

import numpy as np

from ._validation import check_points
from .kernels import copies as _kc

__all__ = ["copy_rows", "exact_copies", "first_copies", "first_rows", "sorted_copies"]


def sorted_copies(P: np.ndarray) -> np.ndarray:
    """Rows equal to the row before them, in lexicographically ordered ``P`` (n, p); bool (n,)."""
    copy = np.zeros(len(P), dtype=bool)
    if len(P) > 1:
        copy[1:] = (P[1:] == P[:-1]).all(axis=1)
    return copy


def exact_copies(points) -> np.ndarray:
    """Which points are exact copies of a point of lower index; bool (n,).

    >>> exact_copies([[0, 0, 0], [1, 0, 0], [0, 0, 0]]).tolist()
    [False, False, True]
    """
    return copy_rows(check_points(points))


def first_copies(points) -> np.ndarray:
    """The index of the first point equal to each point; int64 (n,), ``first[i] == i`` for no copy.

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
