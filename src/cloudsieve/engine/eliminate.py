"""The work store's reads and writes (:class:`StoreCells`) for the ``eliminate`` cells stage, :func:`~.cell_scheme.run_cells`."""

from __future__ import annotations

import numpy as np

__all__ = ["StoreCells"]


class StoreCells:
    """The stage's reads and writes on the work store at *path*; a task opens it (:meth:`open`).

    A share goes to ``simplify/share[cell]`` and ``simplify/band_*``, then
    ``simplify/scored[cell]``; a keep mask to ``simplify/keep_cells``, then
    ``simplify/done[cell]``; the gap bound's fill to ``simplify/fill_cells``."""

    def __init__(self, path: str, group=None) -> None:
        self.path, self.group = path, group

    def open(self) -> "StoreCells":
        from ..store import PointStore

        return StoreCells(self.path, PointStore.open(self.path, "r+").group)

    @property
    def markers(self) -> tuple[np.ndarray, np.ndarray]:
        """The cells done and the cells scored, (P,) bool each."""
        g = self.open().group
        arrays = [g[f"simplify/{name}"] for name in ("done", "scored")]
        # an array no task has marked is all zeros: one listing, not a read per cell (a request each on S3)
        return tuple(np.zeros(a.shape, dtype=bool) if a.nchunks_initialized == 0 else np.asarray(a[:]).astype(bool)
                     for a in arrays)

    def shares(self) -> np.ndarray:
        return np.asarray(self.open().group["simplify/share"][:])

    def core(self, task) -> np.ndarray:
        from .runs import cell_runs, read_runs

        return read_runs(self.group, cell_runs(self.group, task.cell))  # finite float64 (checked at ingest)

    def put_share(self, task, core, row, band, copies) -> None:
        from .runs import write_slices

        bands = [("simplify/band_xyz", task.region, core[band]),
                 ("simplify/band_pos", task.region, band.astype(np.int64))] if len(band) else []
        write_slices(self.group, [*bands, ("simplify/band_count", task.cell, np.array([len(band)], dtype=np.int64)),
                                  ("simplify/duplicates", task.cell, np.array([copies], dtype=np.int64)),
                                  ("simplify/share", task.cell, np.asarray(row, dtype=np.float64)[None, :])])
        self.group["simplify/scored"][task.cell : task.cell + 1] = np.ones(1, dtype=np.uint8)  # after them

    def classes(self, task) -> np.ndarray:
        """The cell's classification codes (n,) uint8 in core order, from ``partition/class``."""
        from ..store.streaming import gathered
        from .runs import cell_runs

        arr = self.group["partition/class"].async_array
        runs = cell_runs(self.group, task.cell)
        parts = gathered(arr.getitem((int(r[0]), slice(int(r[1]), int(r[2])))) for r in runs if r[2] > r[1])
        return np.concatenate([np.asarray(p) for p in parts]) if parts else np.zeros(0, dtype=np.uint8)

    def put_groups(self, task, groups: np.ndarray) -> None:
        """The cell's groups (class policies) in ``simplify/group_cells``, its region (before its share)."""
        self.group["simplify/group_cells"][task.region : task.region + len(groups)] = groups

    def groups(self, task, n: int) -> np.ndarray:
        return np.asarray(self.group["simplify/group_cells"][task.region : task.region + n])

    def groups_at(self, rows: np.ndarray) -> np.ndarray:
        return np.asarray(self.group["simplify/group_cells"].get_orthogonal_selection((rows,)))

    def halo(self, task) -> tuple:
        """The cell's halo from the bands of its sources: points (h, 3), their cells and positions."""
        from .halo import read_band_halo

        return read_band_halo(self.group, task.halo, task.centers, task.cell, task.margin)

    def keep_at(self, rows: np.ndarray) -> np.ndarray:
        """The final keep decisions at *rows* of ``simplify/keep_cells`` (one call of zarr's event loop)."""
        return np.asarray(self.group["simplify/keep_cells"].get_orthogonal_selection((rows,)), dtype=bool)

    def fill_at(self, rows: np.ndarray) -> np.ndarray:
        """The gap bound's fill at *rows* of ``simplify/fill_cells``."""
        return np.asarray(self.group["simplify/fill_cells"].get_orthogonal_selection((rows,)), dtype=bool)

    def put_keep(self, task, keep: np.ndarray) -> None:
        self.group["simplify/keep_cells"][task.region : task.region + len(keep)] = keep
        self.group["simplify/done"][task.cell : task.cell + 1] = np.ones(1, dtype=np.uint8)

    def put_fill(self, task, fill: np.ndarray) -> None:
        """The gap bound's fill of a cell, to ``simplify/fill_cells`` (every cell's again on a resume)."""
        self.group["simplify/fill_cells"][task.region : task.region + len(fill)] = fill

