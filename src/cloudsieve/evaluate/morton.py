"""Morton (Z-order) query order: the leaf that :mod:`.distances` and :mod:`.planes` both use."""

from __future__ import annotations

import numpy as np

__all__ = ["morton_order"]


def morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """Permutation sorting *points* (n, 3) along a Morton (Z-order) curve.
    Used only to make k-d tree queries cache friendly; any order gives the same distances."""
    n = len(points)
    if n < 2:
        return np.arange(n)
    lo = points.min(axis=0)
    span = float((points.max(axis=0) - lo).max()) or 1.0
    q = ((points - lo) * (((1 << bits) - 1) / span)).astype(np.uint64)

    def spread(v: np.ndarray) -> np.ndarray:
        v = v & np.uint64(0x3FF)
        v = (v | (v << np.uint64(16))) & np.uint64(0x30000FF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x300F00F)
        v = (v | (v << np.uint64(4))) & np.uint64(0x30C30C3)
        v = (v | (v << np.uint64(2))) & np.uint64(0x9249249)
        return v

    code = spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")
