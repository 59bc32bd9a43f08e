"""Stage 4, merge: the cells' keep masks scattered back to input order as ``simplify/keep``.

One task per input chunk reads the chunk's runs (``partition/chunk_runs``)
and their cells' regions (``simplify/regions``) from the store, so its
arguments do not grow with the number of cells, and writes its own slice of
``simplify/keep`` (chunk-aligned: no two tasks share a zarr chunk). Export
then writes the kept points in input order.
"""

from __future__ import annotations

import numpy as np

from ..errors import CloudsieveError
from .runs import chunk_runs

__all__ = ["merge_task", "run_merge"]


def merge_task(store_path: str, chunk: int, start: int, stop: int) -> int:
    """Scatter the cells' keep masks back to input order for input chunk *chunk*, points ``[start, stop)``.

    Returns
    -------
    int : kept points in the chunk.
    """
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    g = st.group
    runs = chunk_runs(g, chunk)  # (cell, count, first), cells increasing
    n = stop - start
    if int(runs[:, 1].sum()) != n:  # pragma: no cover - the partition is inconsistent
        raise CloudsieveError(f"{store_path}: chunk at {start} has {n} points but its cells hold {int(runs[:, 1].sum())}")
    labels = np.asarray(g["partition/cell"][start:stop]).astype(np.int64)
    order = np.argsort(labels, kind="stable")
    regions = np.asarray(g["simplify/regions"].get_coordinate_selection(runs[:, 0])) if len(runs) else np.empty(0, np.int64)
    # positions in the cell-ordered arrays of the chunk's points, sorted by cell (each run contiguous)
    begin = regions + runs[:, 2]
    idx = np.repeat(begin - np.cumsum(runs[:, 1]) + runs[:, 1], runs[:, 1]) + np.arange(n)
    sorted_keep = np.asarray(g["simplify/keep_cells"].get_coordinate_selection(idx)) if n else np.empty(0, bool)
    keep = np.empty(n, dtype=bool)
    keep[order] = sorted_keep
    g["simplify/keep"][start:stop] = keep
    return int(keep.sum())


def run_merge(store, runner) -> int:
    """The merge stage: one :func:`merge_task` per input chunk of *store* (``simplify/keep`` must exist).

    Returns
    -------
    int : kept points.
    """
    n, step = store.count, store.chunk_size
    args = [(store.path, c, s, min(s + step, n)) for c, s in enumerate(range(0, n, step))]
    return int(sum(runner(merge_task, args, "merge")))
