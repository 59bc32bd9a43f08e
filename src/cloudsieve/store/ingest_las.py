"""LAS/LAZ/COPC files -> point store, as tasks: :func:`ingest_las`.

The driver reads headers only (:func:`.las_plan.plan_las`) and creates the
store's arrays; each task (:func:`ingest_task`) reads the records of one
range of store chunks from the files that hold them (entering a LAZ file
through its chunk table, so a large file is read by many tasks), and writes
that range. Every store chunk is written by one task, no point array passes
through the driver or the scheduler, and a task's memory is bounded by the
chunk size. "xyz" is stored as the LAS integers (int32) with the store's
scale and offset: exact, and the store's smallest form.

The store is written under a temporary name beside the destination and
renamed when complete (as :func:`.ingest.ingest`).
"""

from __future__ import annotations

import logging
import os

import numpy as np

from ..chunk import xyz_bounds
from ..errors import CorruptInputError, InputFormatError
from .las_plan import LasPlan, plan_las
from ..paths import local_path
from .pointstore import PointStore
from .streaming import bound_malloc, gathered, in_process, run_tasks

__all__ = ["ingest_las", "ingest_task"]

logger = logging.getLogger(__name__)

_INT32 = (-(2**31), 2**31 - 1)


def _read_piece(path: str, first: int, n: int, names: list[str], parallel: bool) -> tuple[np.ndarray, dict]:
    """Points ``first .. first + n - 1`` of the LAS/LAZ file *path*: raw X, Y, Z (n, 3) int64 and the attributes
    (LAZ decoded on every core when *parallel*)."""
    import laspy

    from ..io.las import decode_error, record_arrays
    from ..io.las_checks import QUIET_READS

    # one thread per task when the tasks are the parallelism (lazrs' parallel decoder would oversubscribe the
    # cores); the tasks of a run in this process decode on every core (1 M points: 0.25-0.28 s against 0.55-0.57 s)
    backend = laspy.LazBackend.LazrsParallel if parallel else laspy.LazBackend.Lazrs
    with laspy.open(path, laz_backend=backend) as reader:
        try:
            with QUIET_READS.reading():
                _seek(reader, first)
                points = reader.read_points(n)
        except Exception as exc:
            h = reader.header
            raise decode_error(path, int(h.point_count), h.are_points_compressed, first, first + n - 1, exc) from exc
    if len(points) != n:
        raise CorruptInputError(f"{path}: the header says {first + n} points or more but only {first + len(points)} "
                                f"could be read (truncated or corrupt)")
    array = points.array
    raw = np.empty((n, 3), dtype=np.int64)
    for i, dim in enumerate(("X", "Y", "Z")):
        raw[:, i] = array[dim]
    return raw, record_arrays(points, names)


def _seek(reader, first: int) -> None:
    """Move *reader* to point *first*: LAZ with fixed-size chunks through the chunk table (decoding from the
    chunk's start only); variable-size chunks (COPC) by decoding and dropping the points before, in blocks."""
    if not first:
        return
    vlr = next((v for v in reader.header.vlrs if type(v).__name__ == "LasZipVlr"), None)
    if vlr is None or int.from_bytes(bytes(vlr.record_data)[12:16], "little") != 0xFFFFFFFF:
        reader.seek(first)
        return
    left = first
    while left:
        got = len(reader.read_points(min(left, 1_000_000)))
        if got == 0:
            raise EOFError(f"the file ends before point {first}")
        left -= got


def ingest_task(store_path: str, row_start: int, row_stop: int, pieces: list[tuple], parallel: bool = False) -> dict:
    """Write rows ``[row_start, row_stop)`` of the store from *pieces* (a task; see :meth:`LasPlan.tasks`), LAZ
    decoded on every core when *parallel* (the tasks run in this process, one after the other).

    Returns
    -------
    dict
        ``"mins"``, ``"maxs"``: the stored integers' per-axis extremes (lists of 3 ints).
    """
    bound_malloc()
    group = _open_group(store_path)
    names = [n for n in group.array_keys() if n != "xyz"]
    parts_xyz, parts, mins, maxs = [], [], [], []
    for path, first, n, factors in pieces:
        raw, arrays = _read_piece(path, int(first), int(n), names, parallel)
        mult, add = np.asarray(factors, dtype=np.int64)
        if np.any(mult != 1) or np.any(add != 0):
            raw = raw * mult + add  # exact: integer factors (see las_plan)
        lo, hi = xyz_bounds(raw)  # the stored int32 have the same extremes (checked to fit below)
        mins.append(lo)
        maxs.append(hi)
        if np.any(lo < _INT32[0]) or np.any(hi > _INT32[1]):
            raise InputFormatError(f"{path}: re-quantised to the cloud's scale and offset, its coordinates do not "
                                   f"fit LAS int32 (points {first} to {first + n - 1})")
        parts_xyz.append(raw.astype(np.int32))
        parts.append(arrays)
    xyz = parts_xyz[0] if len(parts_xyz) == 1 else np.concatenate(parts_xyz)
    block = {"xyz": xyz}
    for name in names:
        block[name] = parts[0][name] if len(parts) == 1 else np.concatenate([p[name] for p in parts])
    if len(xyz) != row_stop - row_start:  # pragma: no cover - the plan is consistent
        raise CorruptInputError(f"{store_path}: rows {row_start}..{row_stop} got {len(xyz)} points")
    sel = slice(int(row_start), int(row_stop))
    gathered(group[name].async_array.setitem(sel, block[name]) for name in block)
    return {"mins": np.min(mins, axis=0).tolist(), "maxs": np.max(maxs, axis=0).tolist()}


def _open_group(path: str):
    import zarr

    from ..paths import zarr_store

    return zarr.open_group(zarr_store(path, read_only=False), mode="r+")


def ingest_las(
    sources: list[str],
    store: str | os.PathLike,
    *,
    run=None,
    chunk_size: int,
    overwrite: bool = False,
    plan: LasPlan | None = None,
) -> PointStore:
    """Ingest the LAS/LAZ/COPC files *sources*, one cloud, into a new store at *store*, as tasks.

    Parameters
    ----------
    sources : list of str
        The files, in order (:func:`cloudsieve.io.sources.expand_sources`).
    store : str or path-like
        The new store (a local folder, written under a temporary name and
        renamed when complete, or an fsspec URL).
    run : Runner, optional
        Runs the tasks (:class:`cloudsieve.engine.runner.Runner`); None: one
        after the other in this process.
    chunk_size : int
        Points per store chunk (and per task).
    overwrite : bool
        Replace an existing store.
    plan : LasPlan, optional
        The plan when the caller already made it (:func:`.las_plan.plan_las`).

    Returns
    -------
    PointStore
        Opened read-only.

    Raises
    ------
    MismatchedInputsError, CorruptInputError, DestinationExistsError, ...
    """
    from ..errors import EmptyInputError
    from ..atomic import check_destination, make_temp_path, remove, replace

    store = os.fspath(store)
    plan = plan if plan is not None else plan_las(list(sources))
    if plan.total == 0:
        raise EmptyInputError(f"{sources[0] if len(sources) == 1 else sources[0] + ' and the rest'} holds no points")
    local = local_path(store)
    if local is not None:
        check_destination(local, overwrite)
        target = make_temp_path(local, directory=True)
    else:
        target = store
    encoding = {"scale": plan.scale.tolist(), "offset": plan.offset.tolist()}
    try:
        new = PointStore.create(target, dtypes=plan.dtypes, chunk_size=chunk_size, count=plan.total,
                          overwrite=overwrite or local is not None, xyz_encoding=encoding)
        tasks = plan.tasks(chunk_size)
        parallel = in_process(run, len(tasks))
        args = [(target, lo, hi, pieces, parallel) for lo, hi, pieces in tasks]
        results = run_tasks(run, ingest_task, args, "ingest: read")
        lo = np.min([r["mins"] for r in results], axis=0) * plan.scale + plan.offset
        hi = np.max([r["maxs"] for r in results], axis=0) * plan.scale + plan.offset
        header = dict(plan.header)
        header["mins"], header["maxs"] = lo.tolist(), hi.tolist()
        meta = {
            "count": plan.total,
            "bounds": [lo.tolist(), hi.tolist()],
            "format": plan.format,
            "header": header,
            "dimensions": list(plan.dtypes),
            "chunk_size": int(chunk_size),
            "source": os.path.abspath(plan.paths[0]) if len(plan.paths) == 1 else [os.path.abspath(p) for p in plan.paths],
            "dropped_invalid": 0,
            "xyz_encoding": encoding,
        }
        new.finish(meta)
    except BaseException:
        if local is not None:
            remove(target)
        raise
    if local is not None:
        replace(target, local)
    logger.info("ingested %d points from %d file%s into %s", plan.total, len(plan.paths),
                "" if len(plan.paths) == 1 else "s", store)
    return PointStore.open(store)
