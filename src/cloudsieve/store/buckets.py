"""Grouping a store's points by an integer key, out of core: :func:`bucket` and :class:`Buckets`.

For the tiled export (a key per tile) and the COPC writer (a key per octree
node). One map task per store chunk sorts the chunk's points by key
(stable) into its row of scratch arrays, each point one packed record, and
returns only its distinct keys and counts; nothing of size N passes
through the driver. Layout under ``export/<name>/``::

    records  uint8 (n_chunks, C, B)  row c: chunk c's points sorted by key, records of B
                                     bytes ("xyz" float64 (3,) first; attribute "fields")
    runs     int64 (nnz, 3)          rows (chunk, start, count), by key, chunks increasing
    ptr      int64 (K + 1,)          the runs of key i: runs[ptr[i]:ptr[i + 1]]
    counts   int64 (K,)              points per key
    keys     int64 (K,)              the distinct keys, increasing; written last: the
                                     mark of complete buckets

Example
-------
>>> from functools import partial
>>> from cloudsieve.store.tiles import tile_keys
>>> b = bucket(store, partial(tile_keys, tile_size=100.0), "tiles")  # doctest: +SKIP
>>> points = b.read(b.keys[0])  # {"xyz": (n, 3) float64, ...}  # doctest: +SKIP
>>> b.delete()  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from functools import partial

import numpy as np

from ..errors import ArrayNotFoundError, InvalidParameterError
from ..paths import local_path
from .. import handles
from .codecs import record_compressors
from .pointstore import PointStore
from .streaming import gathered

__all__ = ["bucket", "Buckets", "bucket_chunk", "open_runs", "read_runs", "iter_runs"]

logger = logging.getLogger(__name__)

#: zarr chunk of the scratch rows, in points (REMOTE_INNER_CHUNK on object storage, where each is a request)
INNER_CHUNK = 16384
REMOTE_INNER_CHUNK = 65536
_EMPTY = np.empty((0,), dtype=np.int64)


def _prefix(name: str) -> str:
    if not name or "/" in name:
        raise InvalidParameterError(f"bucket name must be a non-empty name without '/', got {name!r}")
    return f"export/{name}"


def _names(store: PointStore) -> list[str]:
    """The attributes bucketed: "xyz" first, then every other input dimension."""
    return ["xyz"] + [d for d in store.dimensions if d != "xyz"]


def _record_dtype(store: PointStore) -> np.dtype:
    """The packed record of one point: every attribute bucketed, "xyz" float64 (3,) first."""
    dtypes = store.dtypes
    dtypes["xyz"] = (np.dtype(np.float64), (3,))  # coordinates as PointStore.read gives them, whatever the store keeps
    return np.dtype([(d, dtypes[d][0], dtypes[d][1]) for d in _names(store)])


def _fields(dtype: np.dtype) -> list:
    """*dtype*'s fields as JSON: [[name, dtype string, shape], ...]."""
    return [[n, dtype[n].base.str, list(dtype[n].shape)] for n in dtype.names]


def _check_mask(store: PointStore, mask: str) -> None:
    arr = store.array(mask)
    if arr.ndim != 1 or arr.shape[0] != store.count:
        raise InvalidParameterError(
            f"{store.path}: mask {mask!r} must be 1-D with {store.count} entries (one per point), "
            f"got shape {tuple(arr.shape)}")
    if np.dtype(arr.dtype) != np.bool_:
        raise InvalidParameterError(f"{store.path}: mask {mask!r} must be boolean, got dtype {arr.dtype}")


def bucket_chunk(store_path: str, name: str, chunk: int, start: int, stop: int, keys: Callable,
                 mask: str | None, packing: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Map task of :func:`bucket`: key, sort (stable) and write chunk *chunk*'s selected points.

    Reads every array once, in one event-loop call, and decodes only the
    selected points' coordinates. Returns the chunk's distinct keys,
    increasing, and their counts: (r,) int64 each.
    """
    store = PointStore.open(store_path, "r+")
    out = store.group[f"{_prefix(name)}/records"].with_config({"write_empty_chunks": True})  # no scan for zeros
    record = _record(out)
    names = _names(store)
    arrays = [store.array(d) for d in names] + ([store.array(mask)] if mask is not None else [])
    got = [np.asarray(v) for v in gathered(a.async_array.getitem(slice(start, stop)) for a in arrays)]
    rows = np.flatnonzero(got.pop()) if mask is not None else None
    sel = store.decode_xyz(got[0] if rows is None else got[0].take(rows, axis=0))
    n = len(sel)
    k = np.asarray(keys(sel))
    if k.shape != (n,) or not np.issubdtype(k.dtype, np.integer):
        raise InvalidParameterError(
            f"keys({n} points) must return an integer array of shape ({n},), got {k.dtype} {k.shape}")
    k = k.astype(np.int64, copy=False)
    order = np.argsort(k, kind="stable")
    sk = k[order]
    heads = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]]) if n else _EMPTY
    if n:
        take = order if rows is None else rows[order]  # the selected points in key order, packed
        rec = (packing or partial(_pack, record))(sel, dict(zip(names[1:], got[1:])), take, order)
        out[chunk, :n] = rec.view(np.uint8).reshape(n, record.itemsize)
    return sk[heads], np.diff(np.r_[heads, n]).astype(np.int64)


def _pack(record: np.dtype, xyz: np.ndarray, arrays: dict[str, np.ndarray], take: np.ndarray,
          order: np.ndarray) -> np.ndarray:
    """Packed records of *record* of the points ``arrays[name][take]``, their coordinates ``xyz[order]``."""
    rec = np.empty(len(take), dtype=record)
    rec["xyz"] = xyz.take(order, axis=0)
    for d in record.names[1:]:
        rec[d] = arrays[d].take(take, axis=0)
    return rec


def bucket(store: PointStore | str | os.PathLike, keys: Callable[[np.ndarray], np.ndarray], name: str, *,
           mask: str | None = None, run=None, packing: Callable | None = None) -> Buckets:
    """Group the points of *store* (all, or those of *mask*) by ``keys(xyz)``, out of core.

    Parameters
    ----------
    store : PointStore or str
        The store or its path (local, or a URL every worker can reach).
    keys : callable
        ``keys(xyz (n, 3) float64) -> (n,) integer``; module-level or a
        :func:`functools.partial` of one (it is pickled into the tasks).
    name : str
        Scratch name: arrays under ``export/<name>/``, replaced when present.
    mask : str, optional
        A boolean store array, one entry per point: only its True points are bucketed.
    run : callable, optional
        ``run(func, argument_tuples, stage)`` (a :class:`cloudsieve.engine.runner.Runner`);
        None runs the tasks here in turn.
    packing : callable, optional
        ``packing(xyz, arrays, take, order) -> records``: the records written
        in place of the default ones, of the points ``arrays[name][take]``
        (a store chunk's attributes) whose coordinates are ``xyz[order]``
        (the selected points' float64), with a ``dtype()`` method (e.g. :class:`cloudsieve.io.las.LasPacking`:
        the output's LAS records); pickled into the tasks. :func:`read_runs`
        then gives the records' fields, :func:`iter_runs` with ``records=True`` the records.

    Returns
    -------
    Buckets
        Delete its scratch with :meth:`Buckets.delete` when done.

    Raises
    ------
    InvalidParameterError
        A bad *name* or *mask*, or *keys* not returning one integer per point.
    ArrayNotFoundError
        No array *mask* in the store.
    """
    if not isinstance(store, PointStore):
        store = PointStore.open(os.fspath(store), "r")
    prefix = _prefix(name)
    if mask is not None:
        _check_mask(store, mask)
    n, chunk = store.count, store.chunk_size
    starts = list(range(0, n, chunk))
    store.delete_array(prefix)
    record = _record_dtype(store) if packing is None else np.dtype(packing.dtype())
    b = record.itemsize
    local = local_path(store.path) is not None
    inner = min(INNER_CHUNK if local else REMOTE_INNER_CHUNK, chunk)  # a row: one object (shard)
    arr = store.create_array(f"{prefix}/records", shape=(len(starts), -(-chunk // inner) * inner, b), dtype="uint8",
                             chunks=(1, inner, b), shards=(1, -(-chunk // inner) * inner, b),
                             codecs=record_compressors(b, local))
    arr.attrs.update({"fields": _fields(record)})
    args = [(store.path, name, c, s, min(s + chunk, n), keys, mask, packing) for c, s in enumerate(starts)]
    try:
        results = [bucket_chunk(*a) for a in args] if run is None else run(bucket_chunk, args, f"bucket {name}")
        keys_, counts, ptr, runs = _run_table(results)
        store.create_array(f"{prefix}/runs", data=runs, chunks=(max(1, min(len(runs), 65536)), 3))
        for what, data in (("ptr", ptr), ("counts", counts), ("keys", keys_)):  # keys last: the mark of complete
            store.create_array(f"{prefix}/{what}", data=data, chunks=(max(1, min(len(data), 65536)),))
    except BaseException:
        store.delete_array(prefix)  # no half-written scratch left in the store
        raise
    logger.info("bucket %s: %d points of %s in %d keys, %d runs", name, int(counts.sum()), store.path, len(keys_),
                len(runs))
    out = Buckets(store.path, name, keys_, counts, ptr)
    out._table = runs
    return out


def _run_table(results: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(keys, counts, ptr, runs) from the map tasks' (keys, counts) per chunk: runs by key, then chunk."""
    ks = np.concatenate([r[0] for r in results]) if results else _EMPTY
    cnt = np.concatenate([r[1] for r in results]) if results else _EMPTY
    chunk_of = np.repeat(np.arange(len(results), dtype=np.int64), [len(r[0]) for r in results])
    first = np.concatenate([np.cumsum(r[1]) - r[1] for r in results]) if results else _EMPTY
    order = np.lexsort((chunk_of, ks))
    ks, cnt = ks[order], cnt[order]
    heads = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]]) if len(ks) else _EMPTY
    runs = np.stack([chunk_of[order], first[order], cnt], axis=1).astype(np.int64).reshape(-1, 3)
    counts = np.add.reduceat(cnt, heads) if len(heads) else _EMPTY
    return ks[heads].astype(np.int64), counts.astype(np.int64), np.r_[heads, len(ks)].astype(np.int64), runs


def _record(arr) -> np.dtype:
    """The packed record of the scratch array *arr*, from its "fields" attribute."""
    return np.dtype([(n, np.dtype(t), tuple(shape)) for n, t, shape in arr.attrs["fields"]])


def open_runs(store_path: str, name: str) -> tuple:
    """The scratch of buckets *name* opened for reading: (zarr array, record dtype), once per process and stage."""
    import zarr

    from ..paths import zarr_store

    def make() -> tuple:
        # the array alone: opening the whole store costs every task its reads
        arr = zarr.open_array(zarr_store(str(store_path), read_only=True), path=f"{_prefix(name)}/records",
                              mode="r", zarr_format=3)
        return arr, _record(arr)

    return handles.once((str(store_path), "records", name), make)  # once per stage in a task's process


def _read_records(store_path: str, name: str, runs: np.ndarray, scratch: tuple | None) -> np.ndarray:
    """The packed records (n,) of the points of *runs*, runs in order."""
    arr, record = open_runs(store_path, name) if scratch is None else scratch
    runs = np.asarray(runs, dtype=np.int64).reshape(-1, 3)
    # every run in one event-loop call (the codecs run concurrently)
    got = gathered(arr.async_array.getitem((int(c), slice(int(s), int(s + k)))) for c, s, k in runs)
    if not got:
        raw = np.empty((0, record.itemsize), np.uint8)
    else:
        raw = np.concatenate([np.asarray(g) for g in got]) if len(got) > 1 else np.asarray(got[0])
    return np.ascontiguousarray(raw).view(record).reshape(-1)


def read_runs(store_path: str, name: str, runs: np.ndarray, scratch: tuple | None = None) -> dict[str, np.ndarray]:
    """Every attribute of the points of *runs* (rows (chunk, start, count)), runs in order.

    The task-side read; needs no index. *scratch*: :func:`open_runs`'s, else opened here.
    Returns ``{"xyz": (n, 3) float64, attribute: (n,) or (n, k), ...}``.
    """
    rec = _read_records(store_path, name, runs, scratch)
    return {d: np.ascontiguousarray(rec[d]) for d in rec.dtype.names}


def iter_runs(store_path: str, name: str, runs: np.ndarray, max_points: int,
              scratch: tuple | None = None, records: bool = False) -> Iterator:
    """:func:`read_runs` in blocks of whole runs of at most *max_points* points (or one larger run).

    A run is at most one store chunk, so memory stays bounded by the chunk size.
    *records*: each block as its packed records (n,) instead of a dict of fields.
    """
    scratch = open_runs(store_path, name) if scratch is None else scratch
    runs = np.asarray(runs, dtype=np.int64).reshape(-1, 3)
    ends = np.cumsum(runs[:, 2])
    a = 0
    while a < len(runs):
        base = ends[a] - runs[a, 2]
        b = max(a + 1, int(np.searchsorted(ends, base + int(max_points), side="right")))
        if records:
            yield _read_records(store_path, name, runs[a:b], scratch)
        else:
            yield read_runs(store_path, name, runs[a:b], scratch)
        a = b


class Buckets:
    """The driver's index of a store's points grouped by key (made by :func:`bucket`).

    Holds *keys* and *counts* (K,) int64, *ptr* (K + 1,) (the runs of
    ``keys[i]`` are rows ``ptr[i]:ptr[i + 1]`` of the run table) and the run
    table, nothing of size N. Hand tasks ``(store_path, name, buckets.runs(key))``
    rather than this object, so each does not load the whole index. Pickles;
    :meth:`open` reopens it.
    """

    def __init__(self, store_path: str, name: str, keys: np.ndarray, counts: np.ndarray, ptr: np.ndarray) -> None:
        self.store_path = str(store_path)
        self.name = name
        self.keys = keys
        self.counts = counts
        self.ptr = ptr
        self._table: np.ndarray | None = None  # the run table, read on first use

    @classmethod
    def open(cls, store: PointStore | str | os.PathLike, name: str) -> Buckets:
        """The buckets *name* of *store* (a :class:`PointStore` or its path).

        Raises
        ------
        ArrayNotFoundError
            The store holds no complete buckets *name*.
        """
        if not isinstance(store, PointStore):
            store = PointStore.open(os.fspath(store), "r")
        prefix = _prefix(name)
        if f"{prefix}/keys" not in store.group:
            raise ArrayNotFoundError(f"{store.path} holds no complete buckets {name!r} (no {prefix}/keys)")
        g = store.group
        return cls(store.path, name, np.asarray(g[f"{prefix}/keys"][:]), np.asarray(g[f"{prefix}/counts"][:]),
                   np.asarray(g[f"{prefix}/ptr"][:]))

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def names(self) -> list[str]:
        """The attributes :meth:`read` returns, "xyz" first."""
        return list(open_runs(self.store_path, self.name)[1].names)

    def runs(self, key: int) -> np.ndarray:
        """The runs of *key*: (r, 3) int64 rows (chunk, start, count), chunks increasing; none for an absent key."""
        i = int(np.searchsorted(self.keys, key))
        if i >= len(self.keys) or self.keys[i] != key:
            return np.empty((0, 3), dtype=np.int64)
        if self._table is None:
            g = PointStore.open(self.store_path, "r").group
            self._table = np.asarray(g[f"export/{self.name}/runs"][:]).astype(np.int64).reshape(-1, 3)
        return self._table[int(self.ptr[i]):int(self.ptr[i + 1])]

    def read(self, key: int) -> dict[str, np.ndarray]:
        """Every attribute of the points of *key*, in input order (as :func:`read_runs`; n = 0 for an absent key)."""
        return read_runs(self.store_path, self.name, self.runs(key))

    def blocks(self, key: int, max_points: int) -> Iterator[dict[str, np.ndarray]]:
        """The points of *key* as :meth:`read` gives them, in consecutive blocks (see :func:`iter_runs`)."""
        return iter_runs(self.store_path, self.name, self.runs(key), max_points)

    def delete(self) -> None:
        """Delete the scratch arrays (``export/<name>/``) from the store."""
        PointStore.open(self.store_path, "r").delete_array(_prefix(self.name))

    def __repr__(self) -> str:
        return f"Buckets({self.store_path!r}, {self.name!r}, keys={len(self.keys)}, points={int(self.counts.sum())})"
