"""The argument of a cell task (:class:`CellTask`), the tasks of a list of cells and their order: every rule's
cells stage builds its tasks here (:mod:`.cells`, :mod:`.cell_scheme`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CellTask", "cell_tasks", "largest_first"]


@dataclass(frozen=True)
class CellTask:
    """The argument of one cell task: small, independent of the number of cells.

    Attributes
    ----------
    store_path : str
        The store, opened by the task (local path or fsspec URL).
    cell : int
        The cell's id.
    halo : dict int -> int
        Each halo source cell -> the start of its region (empty without a
        density context).
    centers : dict int -> ndarray of shape (3,)
        Centres of the cell and of its halo sources.
    margin : float
        Halo margin.
    region : int
        Start of the cell's region in the cell-ordered ``simplify/*`` arrays.
    params : dict
        The run's parameters (as recorded in the store) and the task's k-d
        tree thread count under ``"threads"``.
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
    """The tasks of *cells*, in the order given.

    *params* gets the tasks' k-d tree thread count under "threads" (not part
    of the parameters recorded for resume: the results do not depend on it).
    The tasks list their halo sources when *halo* is True (None: with a
    density context, ``params["context"]``).
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
    """*cells* by decreasing point count (ties by id): the longest tasks start first, so the
    stage does not end with one worker busy on a large cell while the others wait."""
    cells = np.asarray(cells, dtype=np.int64)
    return [int(j) for j in cells[np.lexsort((cells, -part.cell_counts[cells]))]] if len(cells) else []
