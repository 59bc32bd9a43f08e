"""Stage 4, merge: the cells' keep masks scattered back to input order as ``simplify/keep``.

One task per input chunk reads its runs and their cells' regions from the
store (arguments independent of P) and writes its own chunk-aligned slice.
"""

from __future__ import annotations

import numpy as np

from ..errors import CloudsieveError
from ..core.kernels.scatter import from_groups
from ..store.streaming import gathered
from .runs import chunk_runs

__all__ = ["merge_task", "run_merge"]


def merge_task(store_path: str, chunk: int, start: int, stop: int, fill: bool = False) -> int:
    """Task: input chunk *chunk*'s keep mask in input order, points ``[start, stop)``; returns its kept count.

    *fill*: the gap bound's fill (``simplify/fill_cells``) joins the keep mask."""
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    g = st.group
    runs = chunk_runs(g, chunk)  # (cell, count, first), cells increasing
    n = stop - start
    if int(runs[:, 1].sum()) != n:  # pragma: no cover - the partition is inconsistent
        raise CloudsieveError(f"{store_path}: chunk at {start} has {n} points but its cells hold {int(runs[:, 1].sum())}")
    labels = np.asarray(g["partition/cell"][start:stop])
    regions = g["simplify/regions"]
    first = np.asarray(regions.get_coordinate_selection(runs[:, 0])) if len(runs) else np.empty(0, np.int64)
    # each run's decisions are a slice of the cell-ordered array: read in one event-loop call, put back
    # in input order in one pass
    spans = list(zip(first + runs[:, 2], runs[:, 1]))
    src = _cells(g["simplify/keep_cells"], spans)
    if fill:
        src = src | _cells(g["simplify/fill_cells"], spans)
    offset = np.zeros(regions.shape[0], dtype=np.int64)
    offset[runs[:, 0]] = np.cumsum(runs[:, 1]) - runs[:, 1]
    keep = from_groups(labels, offset, src) if n else np.empty(0, bool)
    g["simplify/keep"][start:stop] = keep
    return int(keep.sum())


def _cells(array, spans) -> np.ndarray:
    """The runs' slices (start, count) of a cell-ordered bool array, concatenated (one event-loop call)."""
    arr = array.async_array
    parts = gathered(arr.getitem(slice(int(b), int(b) + int(c))) for b, c in spans)
    return np.concatenate([np.asarray(p) for p in parts]) if parts else np.empty(0, bool)


def run_merge(store, runner, fill: bool = False) -> list[int]:
    """The merge stage: a :func:`merge_task` per input chunk; kept points per chunk (the export's plan).

    *fill*: join the gap bound's fill."""
    n, step = store.count, store.chunk_size
    args = [(store.path, c, s, min(s + step, n), *((True,) if fill else ())) for c, s in enumerate(range(0, n, step))]
    return [int(k) for k in runner(merge_task, args, "merge")]
