"""Real tiles for the tests: a shared scan cut into square LAZ files with laspy."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np


def cut_tiles(src: Path, dst_dir: Path, nx: int = 2, ny: int = 2) -> list[Path]:
    """Cut the LAS/LAZ file *src* into nx x ny LAZ tiles at its x/y quantiles (about equal counts).

    Each tile keeps the source header (point format, scales, offsets, every
    VLR, the CRS) and its points' raw records, in file order; laspy updates
    counts and bounds. Returns the tile paths, ``{stem}_{i}_{j}.laz``, by
    (i, j).
    """
    las = laspy.read(str(src))
    x, y = np.asarray(las.x), np.asarray(las.y)
    xs = np.quantile(x, np.linspace(0, 1, nx + 1)[1:-1])
    ys = np.quantile(y, np.linspace(0, 1, ny + 1)[1:-1])
    ix, iy = np.searchsorted(xs, x, side="right"), np.searchsorted(ys, y, side="right")
    dst_dir.mkdir(parents=True, exist_ok=True)
    stem = Path(src).name.split(".")[0]
    out = []
    for i in range(nx):
        for j in range(ny):
            tile = laspy.LasData(las.header)
            tile.points = las.points[(ix == i) & (iy == j)]
            path = dst_dir / f"{stem}_{i}_{j}.laz"
            tile.write(str(path))
            out.append(path)
    return out
