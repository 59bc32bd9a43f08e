"""A simplification's checks before any file or store is created or any scheduler started: source,
destination, reusable work store, scheduler (options: :func:`cloudsieve.params.validate`)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import DestinationExistsError, InvalidParameterError, SameSourceDestinationError, UnknownFormatError
from ..io import check_readable, check_writable
from ..io.sources import expand_sources
from ..scheduler import check_scheduler
from .. import storage
from ..paths import holds, local_path, same_path, store_foreign
from ..store import is_store
from . import workstore
from .inprocess import scheduler_for, source_points
from .small import fits_in_memory

__all__ = ["RunChecks", "check_run", "refuse_inputs"]

#: SRC files that name others (a list, a VPC)
_LISTINGS = (".lst", ".txt", ".vpc")


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
    #: the input's points from its headers, when counted and known
    points: int | None = None


def check_run(src: str, dst: str, opts: dict, params: dict, *, client=None) -> RunChecks:
    """Check SRC, DST, the work store and the scheduler; *params*: the run's record, stored in a reused store."""
    overwrite, scheduler, store = opts["overwrite"], opts["scheduler"], opts["store"]
    tiles = opts["tile_size"] is not None
    if tiles:  # as the tiles are written (``out/`` is ``out``)
        dst = dst.rstrip("/") or dst
    dst_local = local_path(dst)
    sources = expand_sources(src)
    inputs = refuse_inputs(src, dst, sources)  # first: overwriting would not help
    src_is_store = is_store(src)
    if src_is_store and holds(src, dst):
        raise SameSourceDestinationError(
            f"destination {dst} lies inside the source store {src}: cloudsieve never writes into its input")
    if dst_local is not None and os.path.exists(dst_local) and not overwrite and os.path.isdir(dst_local) == tiles:
        raise DestinationExistsError(f"{dst} exists; pass overwrite=True to replace it", advice={"overwrite": True})
    for path in sources:
        check_readable(path)
    if opts.get("keep_class") is not None or opts.get("class_ratio") is not None:
        from .class_policy import check_classified

        check_classified(sources, src_is_store)
    if not tiles:
        check_writable(dst, opts["format"], overwrite=overwrite)
    else:
        from ..store.tiles import check_grid, check_tile_destination

        if opts["format"] is not None and opts["format"].lower().lstrip(".") != "laz":
            raise UnknownFormatError(f"{dst}: tiles are written as LAZ, not {opts['format']}")
        check_tile_destination(dst, overwrite, inputs)
        bounds = _header_bounds(src, sources)
        if bounds is not None:
            check_grid(bounds, opts["tile_size"], src)
    points = None  # counted only when this module picks the scheduler
    if scheduler is None and client is None and opts["memory_limit"] is None and opts["workers"] is None:
        points = source_points(sources, src if src_is_store else None)
        scheduler = scheduler_for(points)
    store_path = workstore.work_store_path(src, dst, store, src_is_store)
    if not src_is_store:
        _check_work_store(store_path, dst if tiles else None, inputs)
    # another source's or options' work store is refused before any scheduler is contacted
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


def refuse_inputs(src: str, dst: str, sources: list[str] | None = None) -> list[str]:
    """Refuse *dst* when it is an input of SRC *src* (a file of it, or its list or VPC) or a folder holding one;
    *sources*: ``expand_sources(src)`` when known. Returns the inputs."""
    sources = expand_sources(src) if sources is None else sources
    # a list or VPC is an input too
    inputs = sources + ([src] if src.lower().endswith(_LISTINGS) and not any(same_path(s, src) for s in sources)
                        else [])
    _refuse_inputs_inside(dst, inputs, "destination")
    return inputs


def _refuse_inputs_inside(path: str, sources: list[str], what: str) -> None:
    """Refuse *path* when it is one of *sources* or a folder holding one (replacing it deletes the input)."""
    for source in sources:
        if same_path(source, path):
            raise SameSourceDestinationError(f"{path} is the source: cloudsieve never overwrites its input")
        if holds(path, source):
            raise SameSourceDestinationError(
                f"{what} {path} holds the source {source}: cloudsieve never overwrites its input")


def _check_work_store(store_path: str, tile_folder: str | None, sources: list[str]) -> None:
    """Refuse a work store that is or holds an input, lies in the tile folder, or is a non-store file or folder."""
    _refuse_inputs_inside(store_path, sources, "work store")
    if tile_folder is not None and holds(tile_folder, store_path):
        raise InvalidParameterError(f"work store {store_path} lies in the tile folder {tile_folder}, "
                                    "which is replaced when the tiles are written: choose a store outside it")
    local = local_path(store_path)
    if local is None and storage.isfile(store_path) or local is not None and os.path.lexists(local) and not \
            os.path.isdir(local):
        raise DestinationExistsError(f"work store {store_path} is a file: cloudsieve never replaces a file "
                                     "with a point store (choose another store)")
    found = store_foreign(local or store_path) if local is None or os.path.isdir(local) else None
    if found is not None:
        raise DestinationExistsError(f"work store {store_path} holds {found}: cloudsieve replaces only "
                                     "its own point stores (choose another store)")


def _header_bounds(src: str, sources: list[str]) -> np.ndarray | None:
    """The cloud's bounds (2 x 3) from its LAS/LAZ/COPC headers or its point store, None for other formats."""
    from ..io import detect_format

    if is_store(src):
        from ..store import PointStore

        return PointStore.open(src).bounds
    if any(detect_format(p) not in ("las", "laz", "copc") for p in sources):
        return None
    from ..io.las_layout import read_header

    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for header in map(read_header, sources):
        if header.point_count:
            lo, hi = np.minimum(lo, header.mins), np.maximum(hi, header.maxs)
    return np.stack([lo, hi])
