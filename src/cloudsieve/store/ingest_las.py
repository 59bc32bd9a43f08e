"""LAS/LAZ/COPC files -> point store, as tasks: :func:`ingest_las`.

The driver reads headers only (:func:`cloudsieve.io.las_plan.plan_las`); each
task (:func:`ingest_task`) writes a range of store chunks from the files
holding it. "xyz" is stored as the LAS integers (int32): exact and smallest.
"""

from __future__ import annotations

import logging
import os

import numpy as np

from ..errors import CorruptInputError
from .. import handles
from ..io.las_plan import LasPlan, plan_las
from ..io.las_records import decode_xyz, read_pieces
from ..paths import local_path, store_foreign
from .pointstore import PointStore
from .streaming import bound_malloc, gathered, in_process, run_tasks

__all__ = ["ingest_las", "ingest_task"]

logger = logging.getLogger(__name__)


def ingest_task(store_path: str, row_start: int, row_stop: int, pieces: list[tuple], parallel: bool = False) -> dict:
    """Task: write store rows ``[row_start, row_stop)`` from *pieces* (:meth:`LasPlan.tasks`), LAZ decoded
    on every core when *parallel*; returns ``"mins"``, ``"maxs"``: the stored integers' extremes (3 ints each)."""
    bound_malloc()
    group = handles.open_group(store_path, "ingest", lambda p, _: (_open_group(p), {}))[0]  # once per stage
    names = [n for n in group.array_keys() if n != "xyz"]
    xyz, block, lo, hi = read_pieces(pieces, names, parallel)
    block = {"xyz": xyz, **block}
    if len(xyz) != row_stop - row_start:  # pragma: no cover - the plan is consistent
        raise CorruptInputError(f"{store_path}: rows {row_start}..{row_stop} got {len(xyz)} points")
    sel = slice(int(row_start), int(row_stop))
    gathered(group[name].async_array.setitem(sel, block[name]) for name in block)
    return {"mins": lo.tolist(), "maxs": hi.tolist()}


def _open_group(path: str):
    import zarr

    from ..paths import zarr_store

    return zarr.open_group(zarr_store(path, read_only=False), mode="r+", zarr_format=3, use_consolidated=False)


def ingest_las(
    sources: list[str],
    store: str | os.PathLike,
    *,
    run=None,
    chunk_size: int,
    overwrite: bool = False,
    plan: LasPlan | None = None,
) -> PointStore:
    """Ingest the LAS/LAZ/COPC files *sources* (in order, one cloud) into a new store at *store*, as tasks.

    *store*: a local folder (written under a temporary name and renamed) or
    an fsspec URL; *run* runs the tasks (None: here); *chunk_size*: points per
    store chunk and per task; *plan*: the caller's
    :func:`cloudsieve.io.las_plan.plan_las`. Returns the store, read-only.

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
        check_destination(local, overwrite, folder=True, foreign=store_foreign)
        target = make_temp_path(local, directory=True)
    else:  # an existing object or prefix is never replaced
        if overwrite:
            check_destination(store, overwrite, folder=True, foreign=store_foreign)
        target = store
    encoding = {"scale": plan.scale.tolist(), "offset": plan.offset.tolist()}
    try:
        new = PointStore.create(target, dtypes=plan.dtypes, chunk_size=chunk_size, count=plan.total,
                          overwrite=overwrite or local is not None, xyz_encoding=encoding)
        tasks = plan.tasks(chunk_size)
        parallel = in_process(run, len(tasks))
        args = [(target, lo, hi, pieces, parallel) for lo, hi, pieces in tasks]
        results = run_tasks(run, ingest_task, args, "ingest: read")
        lo, hi = decode_xyz(np.array([np.min([r["mins"] for r in results], axis=0),
                                      np.max([r["maxs"] for r in results], axis=0)]), plan.scale, plan.offset)
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
