"""Point store -> a folder of square LAZ tiles and their ``index.vpc``: :func:`export_tiles`.

Tiles are the squares ``[ix S, (ix + 1) S) x [iy S, (iy + 1) S)`` of a grid
anchored at the CRS's origin, so overlapping clouds exported with the same S
share squares. Points are grouped by tile (:func:`cloudsieve.store.buckets.bucket`),
then one task per non-empty tile writes its LAZ (:func:`cloudsieve.io.open_writer`:
exact records, input order). The folder is written under a temporary name and
renamed when complete (workers must share its file system); the bytes depend
on the store and S only.
"""

from __future__ import annotations

import logging
import os
import re
from functools import partial
from typing import Any

import numpy as np

from .. import progress as _progress
from .. import storage
from ..errors import (DestinationNotWritableError, InvalidParameterError, SameSourceDestinationError,
                      UnknownFormatError)
from ..params import OPTIONS, check, named
from .buckets import bucket, iter_runs, open_runs
from ..paths import holds, local_path
from .pointstore import PointStore

__all__ = ["export_tiles", "check_grid", "check_tile_destination", "tiles_foreign", "tile_keys", "tile_index",
           "tile_name", "VPC_NAME"]

logger = logging.getLogger(__name__)

#: the index written beside the tiles
VPC_NAME = "index.vpc"
#: the grouping's scratch (``export/tiles/`` in the store), deleted at the end
_SCRATCH = "tiles"
_HALF = np.int64(1 << 31)


def _cells(v: np.ndarray, size: float) -> np.ndarray:
    """floor(v / size), corrected so that ``i * size <= v < (i + 1) * size`` holds in float64 (*v* contiguous)."""
    i = np.floor(v / size)
    t = i * size
    i -= v < t
    np.add(i, 1, out=t)
    t *= size
    i += v >= t
    return i


def tile_keys(xyz: np.ndarray, tile_size: float) -> np.ndarray:
    """The tile of each point (n,) int64: ``ix * 2**32 + (iy + 2**31)``, ``ix = floor(x / S)`` (:func:`tile_index`).

    Raises
    ------
    InvalidParameterError
        A tile index outside the signed 32-bit range (S too small for the coordinates).
    """
    xy = np.asarray(xyz, dtype=np.float64)[:, :2]
    ix, iy = (_cells(np.ascontiguousarray(xy[:, a]), tile_size) for a in (0, 1))
    if len(ix) and (min(ix.min(), iy.min()) < -_HALF or max(ix.max(), iy.max()) >= _HALF):
        raise InvalidParameterError(
            f"tile_size {tile_size} is too small for coordinates up to {np.abs(xy).max():.6g}: tile indices "
            f"must fit 32 bits")
    keys = ix.astype(np.int64) << np.int64(32)
    keys += iy.astype(np.int64)
    keys += _HALF
    return keys


def tile_index(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ix, iy) of :func:`tile_keys`' keys: the tile covers ``[ix S, (ix + 1) S) x [iy S, (iy + 1) S)``."""
    keys = np.asarray(keys, dtype=np.int64)
    return keys >> np.int64(32), (keys & np.int64(0xFFFFFFFF)) - _HALF


def tile_name(stem: str, key: int) -> str:
    """The file name of tile *key*: ``{stem}_{ix}_{iy}.laz``."""
    ix, iy = tile_index(np.array([key]))
    return f"{stem}_{int(ix[0])}_{int(iy[0])}.laz"


def write_tile(store_path: str, name: str, runs: np.ndarray, path: str, replace: bool = False,
               records: bool = False) -> dict:
    """Task of :func:`export_tiles`: write a tile's points (its *runs* in buckets *name*) to the LAZ *path*.

    Reads blocks of at most a store chunk; *records*: the buckets hold the
    tile's LAS point records (:func:`_packing`), written as they are.
    Returns the tile's VPC entry (:func:`cloudsieve.io.vpc.describe_tile`).
    """
    from ..io import open_writer
    from ..io.las import laz_backend
    from ..io.vpc import describe_tile

    store = PointStore.open(store_path, "r")
    scratch = open_runs(store_path, name)
    record = scratch[1]
    # as the buckets hold them; LAS records: the store's own
    dtypes = store.dtypes if records else {d: (record[d].base, record[d].shape) for d in record.names}
    with open_writer(path, header=store.header, dtypes=dtypes, source_format=store.source_format,
                     bounds=store.bounds, overwrite=replace, laz_backend=laz_backend(parallel=False)) as writer:
        for block in iter_runs(store_path, name, runs, store.chunk_size, scratch, records):
            if records:
                writer.write_records(block)
            else:
                writer.write(block)
    return describe_tile(path)


def _packing(store: PointStore, dst: str):
    """The tiles' LAS point records, built once by the bucketing tasks (a LAS-sourced store), else None."""
    from ..io.las import LasPacking, las_sourced

    return LasPacking(store.header, store.dimensions, dst) if las_sourced(store.source_format, store.header) else None


def check_grid(bounds: np.ndarray, tile_size: Any, what: str) -> float:
    """The checked *tile_size* for a cloud of *bounds* (2, 3), named *what* in messages.

    Raises
    ------
    InvalidParameterError
        *tile_size* not a positive number, or too small for 32-bit tile indices.
    """
    size = check("tile_size", tile_size)
    if size is None:  # optional elsewhere, required here
        raise named(InvalidParameterError(f"tile_size must be {OPTIONS['tile_size'].describe()}, got None"),
                    "tile_size")
    reach = float(np.abs(np.asarray(bounds, dtype=np.float64)[:, :2]).max())
    if np.isfinite(reach) and not reach / size < 2.0**31 - 1:
        raise named(InvalidParameterError(
            f"tile_size {size} is too small for {what}: coordinates up to {reach:.6g} give tile indices "
            f"beyond 32 bits (tile_size must be at least {reach / (2.0**31 - 2):.3g})"), "tile_size")
    return size


def tiles_foreign(stem: str):
    """A ``foreign`` check for :func:`cloudsieve.atomic.check_destination`: None when a folder holds only
    *stem*'s tiles and ``index.vpc``, else a description of the rest."""
    pattern = re.compile(re.escape(stem) + r"_-?\d+_-?\d+\.laz")

    def foreign(folder: str) -> str | None:
        other = sorted(n for n in storage.listdir(folder, files_only=False)
                       if n != VPC_NAME and not pattern.fullmatch(n))
        if not other:
            return None
        return (f"{len(other)} entr{'y' if len(other) == 1 else 'ies'} other than its tiles and {VPC_NAME} "
                f"({other[0]}{', ...' if len(other) > 1 else ''})")

    return foreign


def check_tile_destination(dst: str, overwrite: bool, sources=()) -> str:
    """Check the tile folder *dst* before any work; returns it as a local path (a URL as it is).

    Refused: a point cloud file's name (``x.ply``), a folder that is or holds
    one of *sources*, an existing file, an existing folder without
    *overwrite*, or one holding anything but its tiles and ``index.vpc``.

    Raises
    ------
    InvalidParameterError, SameSourceDestinationError, DestinationExistsError, DestinationNotWritableError
    """
    from ..atomic import check_destination
    from ..io import detect_format

    local = local_path(dst)
    try:
        fmt = detect_format(dst)
    except UnknownFormatError:
        fmt = None
    if fmt is not None:
        raise named(InvalidParameterError(
            f"{dst}: tile_size writes a folder of LAZ tiles and {VPC_NAME}, and this name is a "
            f"{fmt.upper()} file's; give a folder name, or leave out tile_size for one file"), "tile_size")
    for path in sources:
        if holds(local or dst, path):
            raise SameSourceDestinationError(
                f"destination {dst} is or holds the source {path}: cloudsieve never overwrites its input")
    check_destination(dst, overwrite, folder=True, foreign=tiles_foreign(storage.name(dst)))
    if local is None:
        return dst
    if not os.access(os.path.dirname(local), os.W_OK | os.X_OK):
        raise DestinationNotWritableError(f"cannot write {dst}: folder {os.path.dirname(local)} is not writable")
    return local


def export_tiles(
    store: PointStore | str | os.PathLike,
    dst_dir: str | os.PathLike,
    *,
    tile_size: float,
    mask: str | None = None,
    run=None,
    overwrite: bool = False,
    progress: _progress.ProgressCallback | None = None,
) -> dict:
    """Write the points of *store* (all, or those of *mask*) as square LAZ tiles in *dst_dir*, with an index.vpc.

    One file per non-empty tile, ``{stem}_{ix}_{iy}.laz`` (*stem*: *dst_dir*'s
    name), listed in (ix, iy) order in ``index.vpc`` (:mod:`cloudsieve.io.vpc`).
    *tile_size*: edge S in the CRS's units; *mask*: a bool store array name;
    *run* as :func:`.buckets.bucket`'s; *overwrite* replaces *dst_dir* once
    the new tiles are complete; *progress* gets each tile's points.

    Returns
    -------
    dict
        ``{"tiles": n, "points": m, "files": [paths], "vpc": path, "tile_size": S}``.

    Raises
    ------
    InvalidParameterError
        A bad *tile_size* or *mask*.
    DestinationExistsError, DestinationNotWritableError, SameSourceDestinationError
        (the last one also when *dst_dir* holds the store).
    """
    from ..atomic import replacing
    from ..io.vpc import write_vpc

    if not isinstance(store, PointStore):
        store = PointStore.open(os.fspath(store), "r")
    size = check_grid(store.bounds, tile_size, store.path)
    dst = check_tile_destination(os.fspath(dst_dir).rstrip("/") or os.fspath(dst_dir), overwrite, [store.path])
    stem = storage.name(dst)
    update = _progress.callback(progress)
    if storage.is_url(dst):
        return _export_remote(store, dst, stem, size, mask, run, update)
    try:
        with replacing(dst, directory=True) as tmp:
            packing = _packing(store, dst)
            buckets = bucket(store, partial(tile_keys, tile_size=size), _SCRATCH, mask=mask, run=run, packing=packing)
            names = [tile_name(stem, int(k)) for k in buckets.keys]
            args = [(store.path, _SCRATCH, buckets.runs(k), os.path.join(tmp, f), False, packing is not None)
                    for k, f in zip(buckets.keys, names)]
            entries = [write_tile(*a) for a in args] if run is None else run(write_tile, args, "export: tiles")
            for n in buckets.counts:
                update(int(n))
            write_vpc(os.path.join(tmp, VPC_NAME), entries)
    finally:
        store.delete_array(f"export/{_SCRATCH}")
    points = int(buckets.counts.sum())
    if not points:
        logger.warning("%s: no point to write; wrote an empty tile set", dst)
    logger.info("exported %d points of %s as %d tiles of %g to %s", points, store.path, len(names), size, dst)
    return {"tiles": len(names), "points": points, "files": [os.path.join(dst, f) for f in names],
            "vpc": os.path.join(dst, VPC_NAME), "tile_size": size}


def _export_remote(store: PointStore, dst: str, stem: str, size: float, mask, run, update) -> dict:
    """:func:`export_tiles` to a URL prefix, which has no rename: ``index.vpc``, written last, commits the set.

    A previous index is removed first, its stale tiles once the new ones are
    in; a failure removes the new tiles and leaves no index."""
    from ..io.vpc import write_vpc

    vpc = storage.join(dst, VPC_NAME)
    before = set(storage.listdir(dst)) if storage.isdir(dst) else set()
    storage.remove(vpc)
    names: list[str] = []
    try:
        packing = _packing(store, dst)
        buckets = bucket(store, partial(tile_keys, tile_size=size), _SCRATCH, mask=mask, run=run, packing=packing)
        names = [tile_name(stem, int(k)) for k in buckets.keys]
        args = [(store.path, _SCRATCH, buckets.runs(k), storage.join(dst, f), f in before, packing is not None)
                for k, f in zip(buckets.keys, names)]
        entries = [write_tile(*a) for a in args] if run is None else run(write_tile, args, "export: tiles")
        for n in buckets.counts:
            update(int(n))
        for stale in sorted(before - set(names) - {VPC_NAME}):
            storage.remove(storage.join(dst, stale))
        write_vpc(vpc, entries)
    except BaseException:
        for name in names:
            if name not in before:
                storage.remove(storage.join(dst, name))
        raise
    finally:
        store.delete_array(f"export/{_SCRATCH}")
    points = int(buckets.counts.sum())
    logger.info("exported %d points of %s as %d tiles of %g to %s", points, store.path, len(names), size, dst)
    return {"tiles": len(names), "points": points, "files": [storage.join(dst, f) for f in names],
            "vpc": vpc, "tile_size": size}
