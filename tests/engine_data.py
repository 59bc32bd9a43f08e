"""Generated inputs shared by the engine tests: real LAZ files of synthetic planes."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np


def write_laz(path: Path, xyz: np.ndarray, seed: int = 0) -> Path:
    """A real LAZ file (point format 3, with intensity, colour and GPS time)."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    n = len(xyz)
    las.intensity = rng.integers(0, 65535, n, dtype=np.uint16)
    las.red = rng.integers(0, 65535, n, dtype=np.uint16)
    las.green = rng.integers(0, 65535, n, dtype=np.uint16)
    las.blue = rng.integers(0, 65535, n, dtype=np.uint16)
    las.gps_time = np.arange(n, dtype=np.float64) * 1e-3
    las.classification = rng.integers(0, 6, n, dtype=np.uint8)
    las.write(str(path))
    return path


def plane(n: int, side: float = 100.0, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.random((n, 2)) * side
    z = 0.5 * np.sin(xy[:, 0] / 7.0) + rng.normal(0, 0.02, n)
    return np.c_[xy + 500_000.0, z + 100.0]
