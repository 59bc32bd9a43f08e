"""A simplification's checks before any work (:func:`cloudsieve.engine.simplify.run_simplify`): the source(s),
the destination, the work store a rerun would reuse and the scheduler, in that order, before any file or store
is created and before any scheduler starts. The options were validated before (:func:`cloudsieve.params.validate`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..errors import DestinationExistsError, SameSourceDestinationError
from ..io import check_readable, check_tile_folder, check_writable
from ..io.sources import expand_sources
from ..scheduler import check_scheduler
from ..store import is_store
from . import workstore
from .inprocess import scheduler_for, source_points
from .small import fits_in_memory

__all__ = ["RunChecks", "check_run"]


@dataclass
class RunChecks:
    """What the checks found and the run goes on with."""

    #: SRC's files (one, or the files of one cloud), in order
    sources: list[str]
    #: DST as a local path, None for a URL
    dst_local: str | None
    src_is_store: bool
    #: the scheduler asked for, or the in-process one chosen for a small input
    scheduler: str | None
    store_path: str
    #: the work store is the default one (deleted after success)
    default_store: bool
    #: the work store to reuse (its parameters recorded), None when SRC is ingested anew
    store: object | None
    #: a small input that runs in memory, without a work store (:mod:`.small`)
    in_memory: bool = False
    #: the input's points from its headers, when counted (the scheduler is this module's choice) and known
    points: int | None = None


def check_run(src: str, dst: str, opts: dict, params: dict, *, client=None) -> RunChecks:
    """Check SRC, DST, the work store and the scheduler of a run on the validated *opts*; *params*: the run's
    record (:func:`cloudsieve.params.run_record`), stored in a reused work store."""
    from ..store import local_path, same_path

    overwrite, scheduler, store = opts["overwrite"], opts["scheduler"], opts["store"]
    dst_local = local_path(dst)
    sources = expand_sources(src)
    if any(same_path(p, dst) for p in sources):  # first: overwriting would not help, so it is not suggested
        raise SameSourceDestinationError(f"{dst} is the source: cloudsieve never overwrites its input")
    if dst_local is not None and os.path.exists(dst_local) and not overwrite:
        raise DestinationExistsError(f"{dst} exists; pass overwrite=True to replace it", advice={"overwrite": True})
    for path in sources:
        check_readable(path)
    if opts["tile_size"] is None:
        check_writable(dst, opts["format"], overwrite=True)  # an existing DST was refused above unless overwrite
    else:
        check_tile_folder(dst, opts["format"])
    src_is_store = is_store(src)
    points = None  # counted only when the run's scheduler is this module's choice
    if scheduler is None and client is None and opts["memory_limit"] is None and opts["workers"] is None:
        points = source_points(sources, src if src_is_store else None)
        scheduler = scheduler_for(points)  # small: in process
    store_path = workstore.work_store_path(src, dst, store, src_is_store)
    # a work store of another source or other options is refused before any scheduler is contacted
    st = workstore.reusable_store(src, store_path, src_is_store=src_is_store, overwrite=overwrite,
                                  resume=opts["resume"])
    if st is not None:
        workstore.record_params(st, params, overwrite)
    if client is None and scheduler is not None and "://" in scheduler:
        check_scheduler(scheduler)
    in_memory = points is not None and st is None and not src_is_store and fits_in_memory(sources, dst, opts, points)
    return RunChecks(sources=sources, dst_local=dst_local, src_is_store=src_is_store, scheduler=scheduler,
                     store_path=store_path, default_store=store is None and not src_is_store, store=st,
                     in_memory=in_memory, points=points)
