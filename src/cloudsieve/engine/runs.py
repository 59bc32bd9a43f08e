"""The partition's run tables: two CSR views of the (chunk, cell) runs, and reading points by runs.

A *run* is the points of one cell in one input chunk, contiguous in that
chunk's row of ``partition/xyz``; only nonzero runs are stored::

    chunk_ptr   int64 (n_chunks + 1,)  by chunk: chunk_runs[chunk_ptr[c]:chunk_ptr[c + 1]]
    chunk_runs  int64 (nnz, 3)           rows (cell, count, first), cells increasing;
                                         first = points of that cell in chunks < c
    cell_ptr    int64 (P + 1,)         by cell: cell_runs[cell_ptr[j]:cell_ptr[j + 1]]
    cell_runs   int64 (nnz, 3)           rows (chunk, start, count), chunks increasing
    cell_count  int64 (P,)             points per cell
"""

from __future__ import annotations

import numpy as np

from .. import handles
from ..paths import STORE_ATTR
from ..io.las_records import decode_xyz
from ..store.streaming import gathered

__all__ = ["index_runs", "cell_runs", "chunk_runs", "read_runs", "decode_rows", "write_slices"]

#: zarr chunk of the run tables (runs)
_RUN_CHUNK = 65536
#: tables up to this many runs are read whole once per stage in a task's process (24 MiB)
_TABLE_KEPT = 1 << 20
#: runs held in memory while the run tables are built
_RUN_FLUSH = 1 << 21


def _chunks_1d(n: int) -> int:
    return max(1, min(_RUN_CHUNK, int(n)))


def index_runs(store, nnz: np.ndarray, n_cells: int, chunk_size: int, flush: int | None = None) -> None:
    """Build both run tables and ``cell_count`` from the label pass's ``partition/label_runs``, then delete it.

    Streams the scratch; memory: arrays of size P and n_chunks plus *flush*
    runs (the by-cell view is written in blocks of cells of about *flush*
    runs). *nnz*: runs per chunk (:func:`cloudsieve.engine.label.label_chunk`).
    """
    flush = int(flush or _RUN_FLUSH)
    nnz = np.asarray(nnz, dtype=np.int64)
    n_chunks, p = len(nnz), int(n_cells)
    chunk_ptr = np.zeros(n_chunks + 1, dtype=np.int64)
    np.cumsum(nnz, out=chunk_ptr[1:])
    total = int(chunk_ptr[-1])
    rc = _chunks_1d(total)
    store.delete_arrays([f"partition/{name}"
                         for name in ("chunk_ptr", "chunk_runs", "cell_ptr", "cell_runs", "cell_count")])
    by_chunk = store.create_array("partition/chunk_runs", shape=(total, 3), dtype="int64", chunks=(rc, 3))
    tmp = store.group["partition/label_runs"]
    acc = np.zeros(p, dtype=np.int64)
    n_runs = np.zeros(p, dtype=np.int64)
    buf: list[np.ndarray] = []
    held, pos = 0, 0
    for c in range(n_chunks):
        k = int(nnz[c])
        if k == 0:
            continue
        r = np.asarray(tmp[c, :k])
        cells, cnt = r[:, 0], r[:, 1]  # cells distinct and increasing within a chunk
        buf.append(np.stack([cells, cnt, acc[cells]], axis=1))
        acc[cells] += cnt
        n_runs[cells] += 1
        held += k
        if held >= max(flush, rc):
            rows = np.concatenate(buf)
            m = (len(rows) // rc) * rc  # aligned writes: no zarr chunk written twice
            by_chunk[pos : pos + m] = rows[:m]
            pos += m
            buf, held = [rows[m:]], len(rows) - m
    if held:
        rows = np.concatenate(buf)
        by_chunk[pos : pos + len(rows)] = rows
    cell_ptr = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(n_runs, out=cell_ptr[1:])
    by_cell = store.create_array("partition/cell_runs", shape=(total, 3), dtype="int64", chunks=(rc, 3))
    j0 = 0
    while j0 < p and total:
        # a block of cells whose runs fit the buffer (at least one cell)
        j1 = max(j0 + 1, int(np.searchsorted(cell_ptr, cell_ptr[j0] + flush, side="right")) - 1)
        j1 = min(j1, p)
        base = int(cell_ptr[j0])
        out = np.empty((int(cell_ptr[j1]) - base, 3), dtype=np.int64)
        fill = cell_ptr[j0:j1] - base
        done_points = 0  # points of the by-chunk runs before the slice
        for a in range(0, total, max(flush, rc)):
            b = min(total, a + max(flush, rc))
            rows = np.asarray(by_chunk[a:b])
            cum = done_points + np.cumsum(rows[:, 1]) - rows[:, 1]
            done_points += int(rows[:, 1].sum())
            sel = np.flatnonzero((rows[:, 0] >= j0) & (rows[:, 0] < j1))
            if not len(sel):
                continue
            chunk_of = np.searchsorted(chunk_ptr, a + sel, side="right") - 1
            local = cum[sel] - chunk_of * int(chunk_size)  # start of the run in its row of partition/xyz
            o = np.argsort(rows[sel, 0], kind="stable")  # by cell, chunks stay increasing
            cs = rows[sel, 0][o] - j0
            heads = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
            sizes = np.diff(np.r_[heads, len(cs)])
            rank = np.arange(len(cs)) - np.repeat(heads, sizes)
            at = fill[cs] + rank
            out[at, 0] = chunk_of[o]
            out[at, 1] = local[o]
            out[at, 2] = rows[sel, 1][o]
            fill[cs[heads]] += sizes
        by_cell[base : base + len(out)] = out
        j0 = j1
    for name, data in (("chunk_ptr", chunk_ptr), ("cell_ptr", cell_ptr), ("cell_count", acc)):
        store.create_array(f"partition/{name}", data=data, chunks=(_chunks_1d(len(data)),))
    store.delete_array("partition/label_runs")


def cell_runs(group, cell: int) -> np.ndarray:
    """The runs of *cell*: (r, 4) int64 rows (chunk, start, stop, first), chunks increasing.

    ``first``: the run's first point's position among the cell's points.
    """
    ptr, rows = _table(group, "cell")
    a, b = (int(v) for v in ptr[cell : cell + 2])
    r = np.asarray(rows[a:b]) if b > a else np.empty((0, 3), np.int64)
    first = np.cumsum(r[:, 2]) - r[:, 2]
    return np.stack([r[:, 0], r[:, 1], r[:, 1] + r[:, 2], first], axis=1).astype(np.int64)


def chunk_runs(group, chunk: int) -> np.ndarray:
    """The runs of input chunk *chunk*: (r, 3) rows (cell, count, first), cells increasing."""
    ptr, rows = _table(group, "chunk")
    a, b = (int(v) for v in ptr[chunk : chunk + 2])
    if b <= a:
        return np.empty((0, 3), np.int64)
    return np.asarray(rows[a:b]).astype(np.int64)


def _table(group, by: str) -> tuple:
    """``partition/{by}_ptr`` and ``_runs``: the zarr arrays, or inside a stage, for a small table,
    both read whole once per process (:func:`cloudsieve.handles.once`)."""
    ptr, rows = group[f"partition/{by}_ptr"], group[f"partition/{by}_runs"]
    if not handles.in_stage() or rows.shape[0] > _TABLE_KEPT:
        return ptr, rows
    return handles.once((str(group.store_path), f"{by}_runs"), lambda: (np.asarray(ptr[:]), np.asarray(rows[:])))


def read_runs(group, runs: np.ndarray) -> np.ndarray:
    """Concatenate the ``partition/xyz`` runs ``(chunk, start, stop, ...)``: (n, 3) float64."""
    arr = group["partition/xyz"].async_array
    parts = gathered(arr.getitem((int(r[0]), slice(int(r[1]), int(r[2])))) for r in runs if r[2] > r[1])
    if not parts:
        return np.empty((0, 3))
    return decode_rows(group, np.concatenate([np.asarray(p) for p in parts], axis=0))


def decode_rows(group, raw: np.ndarray) -> np.ndarray:
    """Coordinates (n, 3) float64 of ``partition/xyz`` rows *raw* (LAS integers in such a store)."""
    if raw.dtype == np.float64:
        return raw
    enc = group.attrs[STORE_ATTR]["xyz_encoding"]
    return decode_xyz(raw, np.asarray(enc["scale"], dtype=np.float64), np.asarray(enc["offset"], dtype=np.float64))


def write_slices(group, items) -> None:
    """Write ``group[name][start:start + len(values)] = values`` for each item, concurrently.

    A crash may leave any subset written: a marker written afterwards tells a resumed run they all are."""
    gathered(group[name].async_array.setitem(slice(int(start), int(start) + len(values)), values)
             for name, start, values in items)
