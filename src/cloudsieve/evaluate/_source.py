"""Where the evaluation reads its points from (private).

The original is only streamed (:class:`cloudsieve.store.Chunk`) from an
array, a :class:`cloudsieve.store.PointStore` (or its path) or any file
``open_reader`` reads; the simplified cloud is loaded whole
(:func:`load_points`). NaN or infinite coordinates are refused, or dropped
with *drop_invalid* (:class:`cloudsieve.io.valid.ValidPoints`).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
import os
from typing import Any

import numpy as np

from .. import storage
from ..errors import EmptyInputError, InputFormatError, InputNotFoundError
from ..store import DEFAULT_CHUNK_SIZE, Chunk, PointStore, is_store

logger = logging.getLogger(__name__)

__all__ = ["Source", "open_source", "load_points"]

_NORMALS = ("nx", "ny", "nz")


class Source:
    """A cloud read chunk by chunk.
    Attributes: ``name`` (path or ``"<array>"``), ``count`` (None when unknown without a scan, as for a file with
    *drop_invalid*), ``header``, ``format`` (``"array"``, ``"store"`` or the IO format), ``drop_invalid``,
    ``has_normals`` (chunks then hold ``"normals"`` (n, 3) beside ``"xyz"``)."""

    def __init__(self, obj: Any, chunk_size: int = DEFAULT_CHUNK_SIZE, drop_invalid: bool = False):
        self.chunk_size = int(chunk_size)
        self.drop_invalid = bool(drop_invalid)
        self._warned = False  # the dropped count is logged on the first whole pass only
        self._array = None
        self._store = None
        self._path = None
        self.header: dict = {}
        self.has_normals = False
        if not isinstance(obj, (np.ndarray, PointStore)):
            path = os.fspath(obj)  # a path or a URL (a Path would fold a URL's "//")
            if not storage.exists(path):
                raise InputNotFoundError(f"input not found: {path}")
            obj = PointStore.open(path) if is_store(path) else path
        if isinstance(obj, np.ndarray):
            arr = np.asarray(obj, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != 3:
                raise InputFormatError(f"points must have shape (n, 3), got {arr.shape}")
            self._array = arr
            self.name = "<array>"
            self.format = "array"
            self.count = len(arr)
        elif isinstance(obj, PointStore):
            self._store = obj
            self.name = str(getattr(obj, "path", "<store>"))
            self.format = "store"
            self.count = int(obj.count)
            self.header = dict(getattr(obj, "header", {}) or {})
            self.has_normals = all(n in obj.dimensions for n in _NORMALS)
        else:
            from ..io import open_reader

            self.name = self._path = obj
            with open_reader(self._path, chunk_size=self.chunk_size) as reader:
                self.format = reader.format
                self.count = None if self.drop_invalid else reader.count
                self.header = dict(reader.header or {})
                self.has_normals = all(n in reader.dtypes for n in _NORMALS)

    @property
    def store_path(self) -> str | None:
        """The store's path when the source is a point store (tasks reopen it)."""
        return None if self._store is None else str(self._store.path)

    def chunks(self) -> Iterator[Chunk]:
        """Yield :class:`~cloudsieve.store.Chunk` ``(start, {"xyz": xyz})``, xyz of shape (n, 3) float64, in point order.
        With :attr:`has_normals`, the arrays also hold ``"normals"`` (n, 3) float64."""
        if self._array is not None:
            for start in range(0, len(self._array), self.chunk_size):
                yield Chunk(start, {"xyz": self._array[start : start + self.chunk_size]})
        elif self._store is not None:
            names = ["xyz", *_NORMALS] if self.has_normals else ["xyz"]
            for start, arrays in self._store.chunks(names=names, chunk_size=self.chunk_size):
                yield Chunk(int(start), _arrays(arrays, self.has_normals))
        else:
            from ..io import open_reader
            from ..io.valid import ValidPoints

            valid = ValidPoints(self._path, self.drop_invalid, warn=not self._warned)
            with open_reader(self._path, chunk_size=self.chunk_size) as reader:
                for start, arrays in valid.chunks(reader.chunks()):
                    yield Chunk(start, _arrays(arrays, self.has_normals))
            self._warned = True

    def known_bounds(self) -> np.ndarray | None:
        """Bounds ``[[min], [max]]`` of shape (2, 3) known without a scan (store, array, LAS header), else None."""
        h = self.header or {}
        if self._store is not None:
            return np.asarray(self._store.bounds, dtype=float)
        if self._array is not None:
            a = self._array
            return np.stack([a.min(0), a.max(0)]) if len(a) else None
        if "mins" in h and "maxs" in h:
            return np.array([h["mins"], h["maxs"]], dtype=float)
        return None

    def count_points(self) -> int:
        """The point count, scanning the source once when it is unknown (XYZ text)."""
        if self.count is None:
            self.count = sum(len(chunk.xyz) for chunk in self.chunks())
        return int(self.count)


def _arrays(arrays: dict, normals: bool) -> dict[str, np.ndarray]:
    out = {"xyz": np.asarray(arrays["xyz"], dtype=np.float64)}
    if normals:
        out["normals"] = np.stack([np.asarray(arrays[n], dtype=np.float64) for n in _NORMALS], axis=1)
    return out


def open_source(obj: Any, chunk_size: int = DEFAULT_CHUNK_SIZE, drop_invalid: bool = False) -> Source:
    """Wrap an array, a PointStore, a store path or a file path as a :class:`Source`."""
    if isinstance(obj, Source):
        return obj
    return Source(obj, chunk_size=chunk_size, drop_invalid=drop_invalid)


def load_points(obj: Any, *, what: str = "simplified cloud", drop_invalid: bool = False) -> tuple[np.ndarray, dict, str]:
    """Load a (small) cloud whole: ``(xyz (n,3) float64, header, name)``.
    Raises EmptyInputError (no point) or InvalidPointsError (NaN or infinite coordinates, unless *drop_invalid*)."""
    src = open_source(obj, drop_invalid=drop_invalid)
    if src._array is not None:
        xyz = src._array
    elif src._store is not None:
        xyz = np.asarray(src._store.read("xyz"), dtype=np.float64)
    else:
        parts = [chunk.xyz for chunk in src.chunks()]
        xyz = np.concatenate(parts) if parts else np.empty((0, 3))
    if len(xyz) == 0:
        raise EmptyInputError(f"the {what} is empty (0 points): {src.name}")
    return np.ascontiguousarray(xyz), src.header, src.name
