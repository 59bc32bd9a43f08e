"""The argument of a cell task (:class:`CellTask`) and the tasks of a list of cells, for every rule's cells stage."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CellTask", "cell_tasks", "largest_first"]


@dataclass(frozen=True)
class CellTask:
    """The argument of one cell task: small, independent of the number of cells.

    *halo*: each halo source cell -> its region's start (empty without a
    density context); *centers*: the cell's and its sources' centres;
    *region*: the cell's start in the cell-ordered ``simplify/*`` arrays;
    *params*: the run's recorded parameters plus ``"threads"``.
    """

    store_path: str
    cell: int
    halo: dict
    centers: dict
    margin: float
    region: int
    params: dict


def cell_tasks(store, part, regions: np.ndarray, cells, params: dict, threads: int = 1,
               halo: bool | None = None) -> list[CellTask]:
    """The tasks of *cells*, in the order given; with halo sources when *halo* (None: ``params["context"]``).

    "threads" is not part of the parameters recorded for resume: results do not depend on it.
    """
    c = part.centers
    params = {**params, "threads": int(threads)}
    with_halo = params["context"] if halo is None else halo
    out = []
    for j in cells:
        j = int(j)
        halo = {int(s): int(regions[s]) for s in part.halo_sources(j)} if with_halo else {}
        centers = {j: c[j], **{s: c[s] for s in halo}}
        out.append(CellTask(store.path, j, halo, centers, part.margin, int(regions[j]), params))
    return out


def largest_first(part, cells) -> list[int]:
    """*cells* by decreasing point count (ties by id): the longest tasks start first."""
    cells = np.asarray(cells, dtype=np.int64)
    return [int(j) for j in cells[np.lexsort((cells, -part.cell_counts[cells]))]] if len(cells) else []
