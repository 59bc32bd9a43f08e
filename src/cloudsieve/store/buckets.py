"""Grouping a store's points by an integer key, out of core: :func:`bucket` and :class:`Buckets`.

The tiled export (:mod:`.tiles`: a key per square tile) and the COPC writer
(a key per octree node) both need every point of a key together, for N points
that do not fit in memory. As the partition does with cells
(:mod:`cloudsieve.engine.label`, :mod:`cloudsieve.engine.runs`), one map task
per store chunk computes the keys of the chunk's (kept) points, sorts the
chunk by key (stable) and writes every attribute, sorted, into the chunk's
own row of scratch arrays; it returns only its distinct keys and their
counts. The driver turns those into a run table: the points of key k are, in
input order, its runs ``data[chunk, start:start + count]``. Nothing of size N
passes through the driver or the scheduler; a map task holds two copies of
one chunk.

Layout written into the store, under ``export/<name>/``::

    data/<dim>   (n_chunks, R, ...)  row c: chunk c's selected points sorted by key
                                     (stable); one array per input dimension
                                     ("xyz" float64 (3,) first), R = chunk size
                                     rounded up to the inner chunk; sharded, one
                                     shard per row (a run reads only the inner
                                     chunks it touches)
    runs         int64 (nnz, 3)      rows (chunk, start, count), by key, chunks increasing
    ptr          int64 (K + 1,)      the runs of key i: runs[ptr[i]:ptr[i + 1]]
    counts       int64 (K,)          points per key
    keys         int64 (K,)          the distinct keys, increasing; written last,
                                     so its presence marks complete buckets

Example
-------
>>> from functools import partial
>>> from cloudsieve.store.tiles import tile_keys
>>> b = bucket(store, partial(tile_keys, tile_size=100.0), "tiles")  # doctest: +SKIP
>>> for key in b.keys:  # doctest: +SKIP
...     points = b.read(key)  # {"xyz": (n, 3) float64, "intensity": (n,), ...}
>>> b.delete()  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator

import numpy as np

from ..errors import ArrayNotFoundError, InvalidParameterError
from .pointstore import PointStore
from .streaming import gathered

__all__ = ["bucket", "Buckets", "bucket_chunk"]

logger = logging.getLogger(__name__)

#: inner (zarr) chunk of the scratch rows, in points: the unit a run's read decodes
INNER_CHUNK = 16384
_EMPTY = np.empty((0,), dtype=np.int64)


def _prefix(name: str) -> str:
    if not name or "/" in name:
        raise InvalidParameterError(f"bucket name must be a non-empty name without '/', got {name!r}")
    return f"export/{name}"


def _names(store: PointStore) -> list[str]:
    """The attributes bucketed: "xyz" first, then every other input dimension."""
    return ["xyz"] + [d for d in store.dimensions if d != "xyz"]


def _row_layout(chunk_size: int) -> tuple[int, int]:
    """(R, inner): a scratch row holds R >= chunk_size points in inner chunks of *inner*."""
    inner = min(INNER_CHUNK, chunk_size)
    return -(-chunk_size // inner) * inner, inner


def _check_mask(store: PointStore, mask: str) -> None:
    arr = store.array(mask)
    if arr.ndim != 1 or arr.shape[0] != store.count:
        raise InvalidParameterError(
            f"{store.path}: mask {mask!r} must be 1-D with {store.count} entries (one per point), "
            f"got shape {tuple(arr.shape)}")
    if np.dtype(arr.dtype) != np.bool_:
        raise InvalidParameterError(f"{store.path}: mask {mask!r} must be boolean, got dtype {arr.dtype}")


def bucket_chunk(store_path: str, name: str, chunk: int, start: int, stop: int, keys: Callable,
                 mask: str | None) -> tuple[np.ndarray, np.ndarray]:
    """Map task of :func:`bucket`: key, sort and write the selected points of store chunk *chunk*.

    Reads points ``[start, stop)`` (coordinates through :meth:`PointStore.read`),
    keeps those of *mask*, computes their keys, sorts them by key (stable)
    and writes every attribute, sorted, to row *chunk* of
    ``export/<name>/data/<dim>``.

    Returns
    -------
    keys : ndarray of shape (r,), int64
        The chunk's distinct keys, increasing.
    counts : ndarray of shape (r,), int64
        Points of each key in the chunk.
    """
    store = PointStore.open(store_path, "r+")
    prefix = _prefix(name)
    names = _names(store)
    xyz = store.read("xyz", start, stop)
    others = names[1:]
    got = gathered(store.array(n).async_array.getitem(slice(start, stop)) for n in others)
    arrays = {"xyz": xyz, **{n: np.asarray(v) for n, v in zip(others, got)}}
    if mask is not None:
        rows = np.flatnonzero(store.read(mask, start, stop))
        arrays = {n: v.take(rows, axis=0) for n, v in arrays.items()}
    n = len(arrays["xyz"])
    k = np.asarray(keys(arrays["xyz"]))
    if k.shape != (n,) or not np.issubdtype(k.dtype, np.integer):
        raise InvalidParameterError(
            f"keys({n} points) must return an integer array of shape ({n},), got {k.dtype} {k.shape}")
    k = k.astype(np.int64, copy=False)
    order = np.argsort(k, kind="stable")
    sk = k[order]
    heads = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]]) if n else _EMPTY
    if n:
        gathered(store.group[f"{prefix}/data/{d}"].async_array.setitem((chunk, slice(0, n)), v.take(order, axis=0))
                 for d, v in arrays.items())
    return sk[heads], np.diff(np.r_[heads, n]).astype(np.int64)


def bucket(store: PointStore | str | os.PathLike, keys: Callable[[np.ndarray], np.ndarray], name: str, *,
           mask: str | None = None, run=None) -> Buckets:
    """Group the points of *store* (all, or those of *mask*) by ``keys(xyz)``, out of core.

    Parameters
    ----------
    store : PointStore or str
        The store or its path (local, or a URL every worker can reach).
    keys : callable
        ``keys(xyz)``, xyz ndarray of shape (n, 3), float64 -> ndarray of
        shape (n,), integer: the key of each point. A module-level function
        or a :func:`functools.partial` of one (it is pickled into the tasks).
    name : str
        The scratch's name: arrays under ``export/<name>/`` (replaced when
        present; see the module's docstring for the layout).
    mask : str, optional
        A boolean array of the store, one entry per point (e.g.
        "simplify/keep"): only its True points are bucketed.
    run : callable, optional
        ``run(func, argument_tuples, stage)`` -> results in argument order (a
        :class:`cloudsieve.engine.runner.Runner`); None runs the tasks here,
        one after the other.

    Returns
    -------
    Buckets
        Delete its scratch with :meth:`Buckets.delete` when done.

    Raises
    ------
    InvalidParameterError
        A bad *name*, a *mask* that is not a boolean array of N entries, or
        *keys* returning something other than one integer per point.
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
    dtypes = store.dtypes
    dtypes["xyz"] = (np.dtype(np.float64), (3,))  # coordinates as PointStore.read gives them, whatever the store keeps
    r_len, inner = _row_layout(chunk)
    for d in _names(store):
        dtype, shape = dtypes[d]
        store.create_array(f"{prefix}/data/{d}", shape=(len(starts), r_len, *shape), dtype=dtype,
                           chunks=(1, inner, *shape), shards=(1, r_len, *shape))
    args = [(store.path, name, c, s, min(s + chunk, n), keys, mask) for c, s in enumerate(starts)]
    if run is None:
        results = [bucket_chunk(*a) for a in args]
    else:
        results = run(bucket_chunk, args, f"bucket {name}")
    # the run table: (key, chunk, start, count) per nonzero run, ordered by key then chunk
    ks = np.concatenate([r[0] for r in results]) if results else _EMPTY
    cnt = np.concatenate([r[1] for r in results]) if results else _EMPTY
    chunk_of = np.repeat(np.arange(len(results), dtype=np.int64), [len(r[0]) for r in results])
    first = np.concatenate([np.cumsum(r[1]) - r[1] for r in results]) if results else _EMPTY
    order = np.lexsort((chunk_of, ks))
    ks = ks[order]
    heads = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]]) if len(ks) else _EMPTY
    runs = np.stack([chunk_of[order], first[order], cnt[order]], axis=1).astype(np.int64)
    uniq = ks[heads]
    counts = np.add.reduceat(cnt[order], heads) if len(heads) else _EMPTY
    ptr = np.r_[heads, len(ks)].astype(np.int64)
    store.create_array(f"{prefix}/runs", data=runs.reshape(-1, 3), chunks=(max(1, min(len(runs), 65536)), 3))
    for what, data in (("ptr", ptr), ("counts", counts.astype(np.int64)), ("keys", uniq.astype(np.int64))):
        store.create_array(f"{prefix}/{what}", data=data, chunks=(max(1, len(data)),))
    logger.info("bucket %s: %d points of %s in %d keys, %d runs", name, int(counts.sum()), store.path, len(uniq),
                len(runs))
    return Buckets.open(store.path, name)


class Buckets:
    """The points of a store grouped by key (made by :func:`bucket`), read one key at a time.

    Picklable (arrays of size K and the store's path); in a task, reopen
    with :meth:`Buckets.open` (store path and name) rather than shipping it.

    Attributes
    ----------
    store_path : str
        The store's path or URL.
    name : str
        The scratch's name (``export/<name>/``).
    keys : ndarray of shape (K,), int64
        The distinct keys, increasing.
    counts : ndarray of shape (K,), int64
        Points of each key.
    names : list of str
        The attributes :meth:`read` returns, "xyz" first.
    """

    def __init__(self, store_path: str, name: str, keys: np.ndarray, counts: np.ndarray, ptr: np.ndarray,
                 names: list[str]) -> None:
        self.store_path = str(store_path)
        self.name = name
        self.keys = keys
        self.counts = counts
        self.ptr = ptr
        self.names = list(names)
        self._group = None

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
        names = [d for d in _names(store) if f"{prefix}/data/{d}" in g]
        return cls(store.path, name, np.asarray(g[f"{prefix}/keys"][:]), np.asarray(g[f"{prefix}/counts"][:]),
                   np.asarray(g[f"{prefix}/ptr"][:]), names)

    def __len__(self) -> int:
        return len(self.keys)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_group"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._group = None

    def _g(self):
        if self._group is None:
            self._group = PointStore.open(self.store_path, "r").group
        return self._group

    def runs(self, key: int) -> np.ndarray:
        """The runs of *key*: rows (chunk, start, count), chunks increasing, shape (r, 3), int64.

        Its points are ``export/<name>/data/<dim>[chunk, start:start + count]``
        for the rows in turn; no row for a key without points.
        """
        i = int(np.searchsorted(self.keys, key))
        if i >= len(self.keys) or self.keys[i] != key:
            return np.empty((0, 3), dtype=np.int64)
        a, b = int(self.ptr[i]), int(self.ptr[i + 1])
        return np.asarray(self._g()[f"export/{self.name}/runs"][a:b]).astype(np.int64)

    def _read_runs(self, runs: np.ndarray) -> dict[str, np.ndarray]:
        g = self._g()
        arrays = [g[f"export/{self.name}/data/{d}"].async_array for d in self.names]
        # every run of every attribute in one event-loop call (the codecs run concurrently)
        got = gathered(a.getitem((int(c), slice(int(s), int(s + k)))) for a in arrays for c, s, k in runs)
        r = len(runs)
        out = {}
        for i, d in enumerate(self.names):
            parts = [np.asarray(p) for p in got[i * r:(i + 1) * r]]
            shape = arrays[i].shape[2:]
            out[d] = np.concatenate(parts) if parts else np.empty((0, *shape), dtype=arrays[i].dtype)
        return out

    def read(self, key: int) -> dict[str, np.ndarray]:
        """Every attribute of the points of *key*, in input order.

        Returns
        -------
        dict of str to ndarray
            ``"xyz"``: (n, 3) float64, and each attribute (n,) or (n, k); n = 0
            for a key without points.
        """
        return self._read_runs(self.runs(key))

    def blocks(self, key: int, max_points: int) -> Iterator[dict[str, np.ndarray]]:
        """The points of *key* as :meth:`read` gives them, in consecutive blocks of whole runs.

        A block holds at most *max_points* points, or one run when a run is
        larger (a run is at most one store chunk): memory stays bounded by the
        chunk size however many points the key has.
        """
        runs = self.runs(key)
        if not len(runs):
            return
        ends = np.cumsum(runs[:, 2])
        a = 0
        while a < len(runs):
            base = ends[a] - runs[a, 2]
            b = max(a + 1, int(np.searchsorted(ends, base + int(max_points), side="right")))
            yield self._read_runs(runs[a:b])
            a = b

    def delete(self) -> None:
        """Delete the scratch arrays (``export/<name>/``) from the store."""
        PointStore.open(self.store_path, "r").delete_array(_prefix(self.name))
        self._group = None

    def __repr__(self) -> str:
        return f"Buckets({self.store_path!r}, {self.name!r}, keys={len(self.keys)}, points={int(self.counts.sum())})"
