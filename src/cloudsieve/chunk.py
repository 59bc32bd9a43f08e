"""The one chunk shape every chunk iterator yields (readers, stores, evaluation sources), and the default chunk size."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Chunk", "DEFAULT_CHUNK_SIZE", "take_rows", "xyz_bounds"]

#: points per chunk of every reader, store array and streamed evaluation, unless given
DEFAULT_CHUNK_SIZE = 1_000_000


class Chunk(NamedTuple):
    """Consecutive points from *start* on (``start, arrays = chunk``): ``"xyz"`` (n, 3) float64 and attributes (n,) or
    (n, k)."""

    start: int
    arrays: dict[str, np.ndarray]

    @property
    def xyz(self) -> np.ndarray:
        """The coordinates, ndarray of shape (n, 3)."""
        return self.arrays["xyz"]

    @property
    def stop(self) -> int:
        """One past the index of the block's last point."""
        return self.start + len(self.arrays["xyz"])


def xyz_bounds(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis minimum and maximum of *xyz* (n >= 1, 3), each (3,); column by column (faster than ``min(axis=0)``)."""
    return (np.array([xyz[:, j].min() for j in range(3)]), np.array([xyz[:, j].max() for j in range(3)]))


def take_rows(a: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``a[rows]`` (a new C-ordered array) for integer *rows* of an (n, k) array, by ``a.take`` (faster than fancy
    indexing)."""
    return a.take(rows, axis=0)
