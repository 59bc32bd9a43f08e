"""Point store -> file: :func:`export`, streamed chunk by chunk and atomic (:mod:`cloudsieve.atomic`)."""

from __future__ import annotations

import logging
import os
from contextlib import closing
from typing import Any

import numpy as np
import zarr

from .. import progress as _progress
from .. import storage
from ..errors import InvalidParameterError
from ..params import check
from .streaming import bound_malloc, prefetch
from .chunk import DEFAULT_CHUNK_SIZE
from .pointstore import PointStore, source_and_destination

__all__ = ["export"]

logger = logging.getLogger(__name__)


def _mask_source(store: PointStore, mask: Any):
    """A callable (start, stop) -> bool array, or None for all points."""
    if mask is None:
        return None
    if isinstance(mask, str):
        arr = store.array(mask)
    elif isinstance(mask, zarr.Array):
        arr = mask
    else:
        arr = np.asarray(mask)
    if arr.ndim != 1 or arr.shape[0] != store.count:
        raise InvalidParameterError(f"mask must be 1-D with {store.count} entries (one per point), got shape {tuple(arr.shape)}")
    if np.dtype(arr.dtype) != np.bool_:
        raise InvalidParameterError(f"mask must be boolean, got dtype {arr.dtype}")
    return lambda start, stop: np.asarray(arr[start:stop], dtype=bool)


def _selected(store: PointStore, take, chunk_size: int):
    """The kept points of every chunk of *store*, in point order."""
    for start, chunk in store.chunks(chunk_size=chunk_size):
        if take is not None:
            # row indices once, then take(): faster than a boolean index per array
            rows = np.flatnonzero(take(start, start + len(chunk["xyz"])))
            chunk = {k: v.take(rows, axis=0) for k, v in chunk.items()}
        yield chunk


def export(
    store: PointStore | str | os.PathLike,
    dst: str | os.PathLike,
    *,
    format: str | None = None,
    mask: Any = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    overwrite: bool = False,
    progress: _progress.ProgressCallback | None = None,
    run=None,
    counts: list[int] | None = None,
    tile_size: float | None = None,
    storage_options: dict | None = None,
) -> str:
    """Write the points of *store* (all, or those kept by *mask*) to *dst*, atomically.

    Points keep their input order, every attribute and the source header
    (LAS/LAZ counts and bounds updated).

    Parameters
    ----------
    store : PointStore or str
    dst : str or path-like
        Destination file (.las, .laz, .copc.laz, .ply, .xyz/.txt/.csv/.pts).
    format : str, optional
        Overrides the format found from *dst*'s extension.
    mask : None, str, or 1-D bool array-like of length N
        None keeps every point; a str names a bool array of the store (e.g.
        "simplify/keep"); numpy and zarr arrays are read chunk by chunk.
    chunk_size : int
    overwrite : bool
    progress : callable, optional
        Called with the points written after each chunk (as tasks: once).
    run : Runner, optional
        Runs a LAS/LAZ (:func:`.export_las.export_las`), COPC
        (:func:`.copc.export_copc`) or tiled export as tasks; None runs them
        here. Other formats stream from this process.
    counts : list of int, optional
        Points *mask* keeps in each store chunk, when known (saves a pass).
    tile_size : float, optional
        Write *dst* as a folder of square LAZ tiles (:func:`.tiles.export_tiles`).
    storage_options : dict, optional
        fsspec options of a URL *store* or *dst* (:mod:`cloudsieve.storage`).

    Returns
    -------
    str
        *dst*.

    Raises
    ------
    StoreNotFoundError, SameSourceDestinationError, DestinationExistsError,
    DestinationNotWritableError, UnknownFormatError
    """
    if storage_options is not None:
        with storage.using(check("storage_options", storage_options)):
            return export(store, dst, format=format, mask=mask, chunk_size=chunk_size, overwrite=overwrite,
                          progress=progress, run=run, counts=counts, tile_size=tile_size)
    from ..io import open_writer  # here: see ingest()

    store, dst = source_and_destination(store, dst)
    take = _mask_source(store, mask)
    bound_malloc()
    update = _progress.callback(progress)
    from ..io import detect_format

    named = mask is None or isinstance(mask, str)
    fmt = "tiles" if tile_size is not None else detect_format(dst, format)
    if fmt in ("tiles", "copc") and not named:
        raise InvalidParameterError(f"a {'tiled' if fmt == 'tiles' else 'COPC'} export takes its mask as the name of "
                                    "a bool array of the store")
    if fmt in ("tiles", "copc") or fmt in ("las", "laz") and named:  # as tasks
        if fmt == "tiles":
            from .tiles import export_tiles

            kept = export_tiles(store, dst, tile_size=tile_size, mask=mask, run=run, overwrite=overwrite)["points"]
        elif fmt == "copc":
            from .copc import export_copc

            kept = export_copc(store, dst, mask=mask, run=run, overwrite=overwrite)["points"]
        else:
            from .export_las import export_las

            kept = export_las(store, dst, fmt=fmt, mask=mask, run=run, counts=counts, overwrite=overwrite)
        update(kept)
        _log(kept, store, dst)
        return dst
    kept = 0
    with open_writer(
        dst,
        header=store.header,
        dtypes=store.dtypes,
        format=format,
        source_format=store.source_format,
        overwrite=overwrite,
        bounds=store.bounds,
    ) as writer:
        # the next chunk is read in a thread while this one is encoded
        with closing(prefetch(_selected(store, take, chunk_size))) as chunks:
            for chunk in chunks:
                writer.write(chunk)
                kept += len(chunk["xyz"])
                update(len(chunk["xyz"]))  # written, not read: a bar's total is the kept count
    _log(kept, store, dst)
    return dst


def _log(kept: int, store: PointStore, dst: str) -> None:
    if kept == 0:
        logger.warning("%s: no point kept; wrote an empty cloud", dst)
    logger.info("exported %d of %d points from %s to %s", kept, store.count, store.path, dst)
