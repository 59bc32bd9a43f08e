"""Point store -> file: :func:`export`.

Streams chunk by chunk and is atomic: the file is written under a temporary
name beside the destination and renamed only when complete (see
:class:`cloudsieve.io.Writer`).
"""

from __future__ import annotations

import logging
import os
from contextlib import closing
from typing import Any

import numpy as np
import zarr

from .. import progress as _progress
from ..errors import InvalidParameterError, SameSourceDestinationError
from .streaming import bound_malloc, prefetch
from .paths import same_path
from .chunk import DEFAULT_CHUNK_SIZE
from .pointstore import PointStore

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
    """(points read, the chunk's kept points) for every chunk of *store*, in point order."""
    for start, chunk in store.chunks(chunk_size=chunk_size):
        n = len(chunk["xyz"])
        if take is not None:
            # the rows once, then take(): a boolean index per array finds the rows again for each (6x slower)
            rows = np.flatnonzero(take(start, start + n))
            chunk = {k: v.take(rows, axis=0) for k, v in chunk.items()}
        yield n, chunk


def export(
    store: PointStore | str | os.PathLike,
    dst: str | os.PathLike,
    *,
    format: str | None = None,
    mask: Any = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    overwrite: bool = False,
    progress: _progress.ProgressCallback | None = None,
) -> str:
    """Write the points of *store* (all, or those kept by *mask*) to *dst*.

    Points keep their input order, every attribute and the source header
    (LAS/LAZ counts and bounds updated). The file is written under a
    temporary name and renamed when complete.

    Parameters
    ----------
    store : PointStore or str
        The store or its path/URL.
    dst : str or path-like
        Destination file (.las, .laz, .ply, .xyz/.txt/.csv/.pts).
    format : str, optional
        Overrides the format found from *dst*'s extension.
    mask : None, str, or 1-D bool array-like of length N
        None keeps every point; a str names a bool array of the store (e.g.
        "simplify/keep"); numpy and zarr arrays are read chunk by chunk.
    chunk_size : int
        Points per chunk.
    overwrite : bool
        Replace an existing *dst*.
    progress : callable, optional
        Called with the number of points written after each chunk.

    Returns
    -------
    str
        *dst*.

    Raises
    ------
    StoreNotFoundError, SameSourceDestinationError, DestinationExistsError,
    DestinationNotWritableError, UnknownFormatError
    """
    from ..io import open_writer  # here, not at the top: see ingest()

    dst = os.fspath(dst)
    if not isinstance(store, PointStore):
        store = PointStore.open(os.fspath(store))
    if same_path(store.path, dst):
        raise SameSourceDestinationError(f"destination {dst} is the source {store.path}: cloudsieve never overwrites its input")
    take = _mask_source(store, mask)
    bound_malloc()
    update = _progress.callback(progress)
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
        # the next chunk is read and selected in a thread while this one is encoded (the codecs release the GIL)
        with closing(prefetch(_selected(store, take, chunk_size))) as chunks:
            for _, chunk in chunks:
                writer.write(chunk)
                kept += len(chunk["xyz"])
                update(len(chunk["xyz"]))  # the points written, not read: a bar's total is the kept count
    if kept == 0:
        logger.warning("%s: no point kept; wrote an empty cloud", dst)
    logger.info("exported %d of %d points from %s to %s", kept, store.count, store.path, dst)
    return dst
