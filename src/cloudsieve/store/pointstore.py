"""The point store: a zarr (v3) group holding one cloud, chunked along points.

Layout::

    STORE/
      zarr.json       attribute "cloudsieve": {"version": 1, "count", "bounds", "format",
                      "header", "dimensions", "chunk_size", "complete": true}
      xyz             float64 (N, 3); LAS sources: int32 LAS integers with "xyz_encoding"
      intensity, ...  one array per attribute (laspy names), (N,) or (N, k)
      partition/..., simplify/...   derived arrays of later stages

A store path is a local path or an fsspec URL. Only this module creates and
deletes store arrays; :func:`is_store` is the one test of whether a path holds a store.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import zarr
from zarr.core.sync import sync

from ..errors import (
    ArrayNotFoundError,
    DestinationExistsError,
    InvalidParameterError,
    SameSourceDestinationError,
    StoreNotFoundError,
)
from ..params import check
from .chunk import DEFAULT_CHUNK_SIZE, Chunk
from ..io.las_records import decode_xyz
from ..paths import STORE_ATTR, delete_store, holds, is_store, refuse_source, store_group, zarr_store
from .. import handles, storage
from . import batched
from .codecs import compressors, filters
from .streaming import gathered

__all__ = ["PointStore", "STORE_ATTR", "STORE_VERSION", "is_store", "delete_store", "compressors",
           "source_and_destination"]

logger = logging.getLogger(__name__)

STORE_VERSION = 1


def source_and_destination(store: PointStore | str | os.PathLike, dst: str | os.PathLike) -> tuple[PointStore, str]:
    """The open store and *dst* as a string, refusing a destination that is the store (every export's first check)."""
    dst = os.fspath(dst)
    if not isinstance(store, PointStore):
        store = PointStore.open(os.fspath(store))
    refuse_source(store.path, dst)
    if holds(store.path, dst):
        raise SameSourceDestinationError(
            f"destination {dst} lies inside the source store {store.path}: cloudsieve never writes into its input")
    return store, dst


class PointStore:
    """A cloud of N points in a zarr group, read and extended chunk by chunk.

    Open with :meth:`PointStore.open`; create with :func:`cloudsieve.store.ingest`.
    Its attributes mirror the "cloudsieve" group attribute: *path* (as
    given), *group*, *complete* (False from :meth:`create` until
    :meth:`finish`), *count*, *bounds* (2, 3) float64 ``[[xmin, ymin, zmin],
    [xmax, ymax, zmax]]``, *header* (JSON-serialisable, as ``Reader.header``),
    *source_format*, *dimensions* ("xyz" first) and *chunk_size*.
    """

    def __init__(self, group: zarr.Group, path: str, mode: str = "r", *, meta: dict | None = None) -> None:
        """Wrap an open zarr *group*; *meta* defaults to its "cloudsieve" attribute, which must be complete."""
        if meta is None:
            meta = group.attrs.get(STORE_ATTR)
            if not isinstance(meta, dict) or not meta.get("complete", False):
                raise StoreNotFoundError(f"{path} is not a complete cloudsieve point store (no 'cloudsieve' attributes)")
        self.group = group
        self.path = str(path)
        self.mode = mode
        self._writable: zarr.Group | None = group if mode != "r" else None
        self._groups = {""}  # the groups known to exist ("" the root): arrays under them need no check
        self._absent: set[str] = set()  # derived names this handle deleted: creating one there needs no check
        #: input arrays opened so far (written once, so their metadata is read once)
        self._inputs: dict[str, zarr.Array] = {}
        self._use(meta)

    def _use(self, meta: dict[str, Any]) -> None:
        self._meta = meta
        self.complete = bool(meta.get("complete", False))
        self.count = int(meta["count"])
        self.bounds = np.asarray(meta["bounds"], dtype=np.float64).reshape(2, 3)
        self.header = meta.get("header", {})
        self.source_format = meta["format"]
        self.dimensions = list(meta["dimensions"])
        self.chunk_size = int(meta["chunk_size"])
        enc = meta.get("xyz_encoding")
        self.xyz_scale = None if enc is None else np.asarray(enc["scale"], dtype=np.float64)
        self.xyz_offset = None if enc is None else np.asarray(enc["offset"], dtype=np.float64)

    def decode_xyz(self, raw: np.ndarray) -> np.ndarray:
        """Coordinates (n, 3) float64 from the stored xyz rows *raw*: ``X * scale + offset`` for LAS integers."""
        if self.xyz_scale is None:
            return np.asarray(raw, dtype=np.float64)
        return decode_xyz(raw, self.xyz_scale, self.xyz_offset)

    @classmethod
    def open(cls, path: str | os.PathLike, mode: str = "r") -> PointStore:
        """Open an existing store; *mode* "r", "r+" or "a".

        "r" is read-only, but :meth:`create_array` still opens a writable handle on demand.

        Raises
        ------
        StoreNotFoundError
            When *path* does not exist or is not a complete point store.
        InvalidParameterError
            Unknown *mode*.
        """
        path = os.fspath(path)
        if mode not in ("r", "r+", "a"):
            raise InvalidParameterError(f"mode must be 'r', 'r+' or 'a', got {mode!r}")
        group, meta = handles.open_group(path, mode, store_group)  # once per stage in a task's process
        return cls(group, path, mode, meta=meta)

    @classmethod
    def create(
        cls,
        path: str | os.PathLike,
        *,
        dtypes: dict[str, tuple[np.dtype, tuple]],
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        count: int = 0,
        overwrite: bool = False,
        xyz_encoding: dict | None = None,
    ) -> PointStore:
        """Create an empty, incomplete store at *path*: one array per entry of *dtypes*.

        *dtypes*: name -> (dtype, per-point shape), ``"xyz"`` first (as
        ``Reader.dtypes``); arrays start with *count* points. :meth:`open`
        refuses the store until :meth:`finish`. An existing *path* raises
        :class:`DestinationExistsError` unless *overwrite*. *xyz_encoding*
        ``{"scale": [3], "offset": [3]}`` stores "xyz" as LAS integers (int32, exact).
        """
        path = os.fspath(path)
        if not overwrite and storage.exists(path):
            raise DestinationExistsError(f"{path} exists; pass overwrite=True to replace it", advice={"overwrite": True})
        group = zarr.open_group(zarr_store(path, read_only=False), mode="w")
        # marked (incomplete) before any array: a crash in between leaves no foreign-looking content
        group.attrs.update({STORE_ATTR: {"complete": False}})
        laid: dict[str, Any] = {}  # on object storage: every array's zarr.json at once (the group is new and empty)
        for name, (dtype, shape) in dtypes.items():
            if name == "xyz" and xyz_encoding is not None:
                dtype = np.int32
            options = dict(
                shape=(count, *shape),
                dtype=np.dtype(dtype),
                chunks=(chunk_size, *shape),
                fill_value=0,
                compressors=compressors("input"),
                filters=filters(len(shape)),
                config={"write_empty_chunks": True},  # skip the all-fill-value scan of every chunk
            )
            if batched.remote(group):
                laid.update({k: v for k, v in batched.laid_out(name, options)[0].items() if k != "zarr.json"})
            else:
                group.create_array(name, **options)
        batched.write_all(group, laid)
        meta = {
            "count": int(count),
            "bounds": np.full((2, 3), np.nan),
            "format": None,
            "header": {},
            "dimensions": list(dtypes),
            "chunk_size": int(chunk_size),
            "complete": False,
            "xyz_encoding": xyz_encoding,
        }
        return cls(group, path, "w", meta=meta)

    def finish(self, meta: dict[str, Any]) -> None:
        """Record *meta* (``count``, ``bounds``, ``format``, ``header``, ``dimensions``, ``chunk_size``, ...)
        and mark the store complete: the last step of writing it; ``version`` is added when missing."""
        meta = dict(meta)
        meta.setdefault("version", STORE_VERSION)
        meta["complete"] = True
        self._writable_group().attrs.update({STORE_ATTR: meta})
        self._use(meta)

    @property
    def attrs(self) -> dict:  # the group's attributes (update with ``store.group.attrs.update``)
        return dict(self.group.attrs)

    @property
    def dtypes(self) -> dict[str, tuple[np.dtype, tuple]]:
        """Input attribute name -> (dtype, per-point shape), as ``Reader.dtypes``."""
        out = {}
        for name in self.dimensions:
            arr = self.array(name)
            out[name] = (np.dtype(arr.dtype), tuple(arr.shape[1:]))
        out["xyz"] = (np.dtype(np.float64), (3,))  # decoded from LAS integers where so stored
        return out

    def __contains__(self, name: str) -> bool:
        return name in self.group

    def array(self, name: str) -> zarr.Array:
        """The zarr array *name* (input or derived, e.g. "simplify/keep").

        Raises
        ------
        ArrayNotFoundError
            No array *name* (or *name* is a group).
        """
        if name in self._inputs:
            return self._inputs[name]
        try:
            node = self.group[name]
        except KeyError:
            raise ArrayNotFoundError(f"{self.path} has no array {name!r}; input arrays: {self.dimensions}") from None
        if not isinstance(node, zarr.Array):
            raise ArrayNotFoundError(f"{self.path}: {name!r} is a group, not an array")
        if name in self.dimensions and self.complete:
            self._inputs[name] = node
        return node

    def read(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Points ``start:stop`` of array *name*, (n,) or (n, k) ("xyz" as float64 coordinates)."""
        arr = self.array(name)
        stop = arr.shape[0] if stop is None else min(stop, arr.shape[0])
        values = np.asarray(arr[start:stop])
        return self.decode_xyz(values) if name == "xyz" else values

    def chunks(self, names: Sequence[str] | None = None, chunk_size: int | None = None) -> Iterator[Chunk]:
        """Yield :class:`Chunk` ``(start, {name: array})`` in point order.

        *names* default to every input dimension; *chunk_size* to the store's
        (a multiple of it reads whole zarr chunks).
        """
        step = int(self.chunk_size if chunk_size is None else check("chunk_size", chunk_size))  # params' check
        for start in range(0, self.count, step):
            yield Chunk(start, self.rows(start, start + step, names))

    def rows(self, start: int, stop: int, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Points ``[start, stop)`` of the arrays *names* (default: every input dimension), "xyz" as float64."""
        names = list(self.dimensions if names is None else names)
        arrays = [self.array(n) for n in names]
        sel = slice(int(start), min(int(stop), self.count))
        # all arrays read and decoded concurrently
        got = gathered(a.async_array.getitem(sel) for a in arrays)
        out = {n: np.asarray(v) for n, v in zip(names, got)}
        if "xyz" in out:
            out["xyz"] = self.decode_xyz(out["xyz"])
        return out

    def _writable_group(self) -> zarr.Group:
        if self._writable is None:
            self._writable = zarr.open_group(zarr_store(self.path, read_only=False), mode="r+", zarr_format=3,
                                             use_consolidated=False)
        return self._writable

    def _refresh(self) -> None:  # keep the read handle in sync: store.read(name) sees arrays created or deleted
        handles.forget()
        if self.mode == "r":
            self.group = zarr.open_group(zarr_store(self.path, read_only=True), mode="r", zarr_format=3,
                                         use_consolidated=False)

    def _check_derived(self, name: str) -> None:
        parts = str(name).split("/")
        # a deletion lists and removes everything under the name: never the root nor a path out of the store
        if not str(name).strip("/") or any(p in ("", ".", "..") for p in parts):
            raise InvalidParameterError(f"{self.path}: {name!r} is not a derived array's path (such as 'simplify/keep')")
        if name in self.dimensions or name.split("/")[0] in self.dimensions:
            raise InvalidParameterError(
                f"{self.path}: {name!r} is an input array; derived arrays go under a path such as 'simplify/{name}'"
            )

    def create_array(
        self,
        name: str,
        *,
        shape: Sequence[int] | None = None,
        dtype: Any = None,
        data: np.ndarray | None = None,
        chunks: Sequence[int] | None = None,
        shards: Sequence[int] | None = None,
        fill_value: Any = 0,
        overwrite: bool = False,
        codecs: tuple | None = None,
    ) -> zarr.Array:
        """Create a derived array *name* ("stage/name"), compressed like the input arrays.

        Give *shape* and *dtype*, or *data*. *chunks* default to the store's
        chunk size along axis 0; *shards* is the zarr shard shape; *codecs*
        replaces the compressors. An input dimension as *name*, or a missing
        shape or dtype, raises :class:`InvalidParameterError`.
        """
        self._check_derived(name)
        if data is not None:
            data = np.asarray(data)
            shape, dtype = data.shape, data.dtype
        elif shape is None or dtype is None:
            raise InvalidParameterError(f"{self.path}: array {name!r} needs data, or a shape and a dtype")
        shape = tuple(int(s) for s in shape)
        if chunks is None:
            chunks = (max(1, min(self.chunk_size, shape[0] if shape else 1)), *shape[1:]) if shape else ()
        options: dict[str, Any] = {"shape": shape, "dtype": dtype} if data is None else {"data": data}
        if shards is not None:
            options["shards"] = tuple(shards)
        options.update(chunks=tuple(chunks), fill_value=fill_value, compressors=codecs or compressors())
        group = self._writable_group()
        if batched.remote(group):
            arr = batched.create(group, name, options, overwrite=overwrite, groups=self._groups,
                                 check=not self._known_absent(name))
            parts = name.strip("/").split("/")
            self._absent -= {"/".join(parts[: i + 1]) for i in range(len(parts))}
        else:
            arr = group.create_array(name, overwrite=overwrite, **options)
        self._refresh()
        return arr

    def require_array(
        self, name: str, *, shape: Sequence[int], dtype: Any, chunks: Sequence[int] | None = None, fill_value: Any = 0
    ) -> zarr.Array:
        """The derived array *name* if its shape and dtype match, else a new one (as :meth:`create_array`)."""
        shape = tuple(int(s) for s in shape)
        node = self.group.get(name)
        if isinstance(node, zarr.Array) and node.shape == shape and np.dtype(node.dtype) == np.dtype(dtype):
            return node
        return self.create_array(name, shape=shape, dtype=dtype, chunks=chunks, fill_value=fill_value, overwrite=True)

    def delete_array(self, name: str) -> bool:
        """Delete the derived array or group *name* (e.g. "simplify"); returns False when there was none.

        Raises
        ------
        InvalidParameterError
            *name* is an input array.
        """
        self._check_derived(name)
        group = self._writable_group()
        if self._known_absent(name) or name not in group:
            return False
        if batched.remote(group):  # one listing and one batch of deletes
            sync(batched.delete(group.store, name))
            self._gone([name])
        else:
            del group[name]
        self._refresh()
        return True

    def delete_arrays(self, names: Sequence[str]) -> list[str]:
        """Delete the derived arrays or groups *names*; returns those there were. On object storage one listing of
        their common group finds them all, and one batch deletes them.

        Raises
        ------
        InvalidParameterError
            One of *names* is an input array.
        """
        for name in names:
            self._check_derived(name)
        group = self._writable_group()
        if not batched.remote(group):
            return [name for name in names if self.delete_array(name)]
        found = sync(batched.delete_all(group.store, [n.strip("/") for n in names]))
        self._gone(names)
        if found:
            self._refresh()
        return found

    def _gone(self, names: Sequence[str]) -> None:  # *names* deleted: neither they nor groups under them exist
        under = tuple(n.strip("/") + "/" for n in names)
        self._groups = {g for g in self._groups if not (g + "/").startswith(under)}
        self._absent.update(n.strip("/") for n in names)

    def _known_absent(self, name: str) -> bool:  # deleted by this handle, nothing created under it since
        parts = name.strip("/").split("/")
        return any("/".join(parts[: i + 1]) in self._absent for i in range(len(parts)))

    def __repr__(self) -> str:
        return f"PointStore({self.path!r}, count={self.count}, format={self.source_format!r}, dimensions={self.dimensions})"
