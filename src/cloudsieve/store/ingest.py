"""File -> point store: :func:`ingest`.

Streams chunk by chunk (memory bounded by the chunk size) and is atomic: a
local store is written under a temporary name and renamed when complete; a
URL store is marked complete only at the end (:meth:`PointStore.open`
refuses an incomplete one).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

import numpy as np
import zarr

from .. import progress as _progress
from .. import storage
from ..params import check, validate_params
from ..errors import (
    EmptyInputError,
    SameSourceDestinationError,
    UnknownFormatError,
)
from ..paths import holds, local_path, same_path, store_foreign
from ..chunk import xyz_bounds
from .chunk import DEFAULT_CHUNK_SIZE
from .pointstore import PointStore
from .streaming import bound_malloc, gathered, prefetch

__all__ = ["ingest"]

logger = logging.getLogger(__name__)


class _StoreFiller:
    """Writes incoming blocks to the store arrays in whole, aligned chunks."""

    def __init__(self, group: zarr.Group, names: list[str], chunk_size: int, capacity: int) -> None:
        self.arrays = {n: group[n] for n in names}
        self.chunk_size = chunk_size
        self.capacity = capacity
        self.pending: list[dict[str, np.ndarray]] = []
        self.pending_n = 0
        self.written = 0

    def close(self) -> None:
        self.pending = []

    def add(self, chunk: dict[str, np.ndarray]) -> None:
        n = len(chunk["xyz"])
        if n == 0:
            return
        if self.pending_n == 0 and n == self.chunk_size:
            self._write(chunk, n)
            return
        self.pending.append(chunk)
        self.pending_n += n
        while self.pending_n >= self.chunk_size:
            block = self._take(self.chunk_size)
            self._write(block, self.chunk_size)

    def _take(self, n: int) -> dict[str, np.ndarray]:
        names = list(self.pending[0])
        joined = {k: np.concatenate([p[k] for p in self.pending]) for k in names} if len(self.pending) > 1 else self.pending[0]
        block = {k: v[:n] for k, v in joined.items()}
        rest = {k: v[n:] for k, v in joined.items()}
        self.pending_n -= n
        self.pending = [rest] if self.pending_n else []
        return block

    def _write(self, block: dict[str, np.ndarray], n: int) -> None:
        start, stop = self.written, self.written + n
        if stop > self.capacity:
            self.capacity = stop
            for arr in self.arrays.values():
                arr.resize((stop, *arr.shape[1:]))
        # all arrays compressed and written concurrently
        sel = slice(start, stop)
        gathered(arr.async_array.setitem(sel, block[name]) for name, arr in self.arrays.items())
        self.written = stop

    def flush(self) -> None:
        if self.pending_n:
            n = self.pending_n
            self._write(self._take(n), n)
        if self.capacity != self.written:
            for arr in self.arrays.values():
                arr.resize((self.written, *arr.shape[1:]))
            self.capacity = self.written


@validate_params("ingest")
def ingest(
    src: str | os.PathLike,
    store: str | os.PathLike,
    *,
    format: str | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    drop_invalid: bool = False,
    overwrite: bool = False,
    progress: _progress.ProgressCallback | None = None,
    on_chunk: Callable[[int, np.ndarray, int | None], None] | None = None,
    run=None,
    storage_options: dict | None = None,
    **reader_options: Any,
) -> PointStore:
    """Stream the point cloud file *src* into a new point store *store* (a folder or fsspec URL).

    Parameters
    ----------
    src : str or path-like
        LAS/LAZ/COPC/PLY/E57/XYZ file, or LAS/LAZ/COPC files as one cloud
        (:func:`cloudsieve.io.sources.expand_sources`). LAS sources are
        ingested as tasks (:func:`.ingest_las.ingest_las`, "xyz" as LAS
        integers); other formats stream through this process.
    format : str, optional
        Overrides the format found from *src*'s extension.
    chunk_size : int
        Points per read chunk and per store chunk.
    drop_invalid : bool
        Drop points with NaN or infinite coordinates (counted in the store
        attribute "dropped_invalid") instead of refusing the input.
    overwrite : bool
    progress : callable, optional
        Called with the number of points read after each chunk.
    on_chunk : callable, optional
        ``on_chunk(start, xyz (n, 3) float64, count)`` for each block of valid
        points as stored (*count*: the reader's announced total, or None), e.g.
        :class:`cloudsieve.engine.sample.IngestSample`. Streamed formats only.
    run : Runner, optional
        Runs a LAS source's tasks (:class:`cloudsieve.engine.runner.Runner`); None: here.
    storage_options : dict, optional
        fsspec options of a URL *src* or *store* (:mod:`cloudsieve.storage`).
    **reader_options
        Passed to the reader (XYZ: ``delimiter``, ``columns``, ...).

    Returns
    -------
    PointStore
        The new store, opened read-only.

    Raises
    ------
    InputNotFoundError, InputIsDirectoryError, UnknownFormatError,
    CorruptInputError, InputFormatError, InvalidPointsError, EmptyInputError,
    SameSourceDestinationError, DestinationExistsError,
    DestinationNotWritableError
    """
    if storage_options is not None:
        with storage.using(check("storage_options", storage_options)):  # JSON text as a dict
            return ingest.unchecked(src, store, format=format, chunk_size=chunk_size, drop_invalid=drop_invalid,
                                    overwrite=overwrite, progress=progress, on_chunk=on_chunk, run=run,
                                    **reader_options)
    # imported here: io imports the store's Chunk, so either package can be imported first
    from ..io import open_reader
    from ..atomic import check_destination, make_temp_path, remove, replace
    from ..io.valid import ValidPoints

    src, store = os.fspath(src), os.fspath(store)
    if same_path(src, store):
        raise SameSourceDestinationError(f"destination {store} is the source {src}: cloudsieve never overwrites its input")
    chunk_size = int(chunk_size)  # validated once by the decorator
    bound_malloc()
    update = _progress.callback(progress)
    from ..io.sources import expand_sources
    from ..io.las_plan import is_las_source

    sources = expand_sources(src)
    for path in sources:
        if holds(store, path):
            raise SameSourceDestinationError(
                f"destination {store} is or holds the source {path}: cloudsieve never overwrites its input")
    if format is None and not reader_options and is_las_source(sources):
        from .ingest_las import ingest_las

        st = ingest_las(sources, store, run=run, chunk_size=chunk_size, overwrite=overwrite)
        update(st.count)
        return st
    if len(sources) > 1:
        raise UnknownFormatError(f"{src}: several files are read as one cloud only when all are LAS, LAZ or COPC; "
                                 f"got {', '.join(sorted({os.path.splitext(p)[1] or '(none)' for p in sources}))}")
    local = local_path(store)
    with open_reader(src, format=format, chunk_size=chunk_size, **reader_options) as reader:
        if local is not None:
            check_destination(local, overwrite, folder=True, foreign=store_foreign)
            target = make_temp_path(local, directory=True)
        else:  # an existing object or prefix is never replaced
            if overwrite:
                check_destination(store, overwrite, folder=True, foreign=store_foreign)
            target = store
        try:
            # a local target is a fresh temporary folder; a remote one exists only with overwrite
            new = PointStore.create(
                target, dtypes=reader.dtypes, chunk_size=chunk_size, count=reader.count or 0,
                overwrite=overwrite or local is not None,
            )
            filler = _StoreFiller(new.group, list(reader.dtypes), chunk_size, reader.count or 0)
            lo = np.full(3, np.inf)
            hi = np.full(3, -np.inf)
            # NaN/infinite coordinates refused or dropped
            valid = ValidPoints(src, drop_invalid)
            prefetched = prefetch(reader.chunks())
            for start, chunk in valid.chunks(prefetched, progress=update):
                xyz = chunk["xyz"]
                if on_chunk is not None:
                    on_chunk(start, xyz, reader.count)
                c_lo, c_hi = xyz_bounds(xyz)
                lo, hi = np.minimum(lo, c_lo), np.maximum(hi, c_hi)
                filler.add(chunk)
            if valid.read == 0:
                raise EmptyInputError(f"{src} holds no points")
            filler.flush()
            meta = {
                "count": int(filler.written),
                "bounds": [lo.tolist(), hi.tolist()],
                "format": reader.format,
                "header": reader.header,
                "dimensions": list(reader.dtypes),
                "chunk_size": chunk_size,
                "source": os.path.abspath(src),
                "dropped_invalid": int(valid.invalid),
            }
            new.finish(meta)
        except BaseException:
            if local is not None:
                remove(target)
            raise
        finally:
            if "prefetched" in locals():
                prefetched.close()  # stops the reading thread first
            if "filler" in locals():
                filler.close()
    if local is not None:
        replace(target, local)
    logger.info("ingested %d points from %s into %s", meta["count"], src, store)
    return PointStore.open(store)
