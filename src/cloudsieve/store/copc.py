"""Point store -> COPC file, out of core: :func:`export_copc`.

1. **Bucket** the points by octree node at depth H (:func:`cloudsieve.store.buckets.bucket`,
   :func:`.octree.node_keys`), H the smallest depth <= :data:`.octree.GRID_BITS`
   at which a surface of the cloud's size puts about *task_points* / 4 in a node.
2. **Plan** (driver): a task per top-most node holding <= *task_points* points.
3. **Subtrees**: a task per such node T assigns levels (:func:`.octree.assign_levels`,
   points by cell at depth 7, input order within; a voxel keeps its first point, or
   its point of lowest ``cloudsieve_rank`` when the store has one), writes a LAZ chunk per
   node of T's subtree and T's ancestors' records to scratch files, and
   returns sizes and counts only.
4. **Ancestors**: tasks gather and compress each ancestor's records.
5. **File**: one task writes it (:func:`.copc_file.write_copc`).

Every voxel of a node at depth <= 7 lies inside one node at depth 7, so the
file depends on the cloud and *leaf_points* only, never on the runner,
worker count, *task_points* or H. A local *dst* is written under a
temporary name and renamed; a URL *dst* is one upload, with the same bytes.
Scratch (:mod:`.copc_scratch`) and buckets are removed at the end, also on failure.
"""

from __future__ import annotations

import logging
import uuid
from dataclasses import dataclass
from functools import partial

import numpy as np

from .. import progress as _progress
from .. import storage
from ..errors import InvalidParameterError
from ..atomic import check_destination, make_temp_path, remove, replace
from ..io.las_header import header_from_dict
from ..io.rank import RANK_DIM
from ..paths import refuse_source
from .buckets import bucket, iter_runs
from .copc_file import compress, copc_header, laz_vlr, merge_stats, point_records, record_stats, write_copc
from .copc_scratch import make_scratch, read_records, remove_scratch, scratch_output
from .octree import GRID_BITS, KEY_DEPTH, assign_levels, demorton, group_nodes, node_keys, point_keys, root_cube
from .pointstore import PointStore, source_and_destination

__all__ = ["export_copc", "file_to_copc", "DEFAULT_TASK_POINTS", "DEFAULT_LEAF_POINTS"]

logger = logging.getLogger(__name__)

#: points per subtree task (its memory: about 165 bytes per point)
DEFAULT_TASK_POINTS = 1_000_000
#: points per read of a subtree task's buckets
_READ_BLOCK = 1 << 18
#: a node whose cube holds at most this many points keeps them all (a leaf)
DEFAULT_LEAF_POINTS = 50_000


def _bucket_depth(count: int, task_points: int) -> int:
    """H: the smallest depth (at most GRID_BITS) where a surface's nodes would hold <= task_points / 4 points."""
    depth = 0
    while depth < GRID_BITS and count > (task_points / 4) * 4**depth:
        depth += 1
    return depth


def _plan(keys: np.ndarray, counts: np.ndarray, depth: int, task_points: int) -> list[tuple[int, int, int, int]]:
    """The subtree tasks: (node depth, node Morton key, first bucket, end bucket), in Morton order.

    A bucket goes to its top-most ancestor holding at most *task_points* points, else to itself.
    """
    cut = np.full(len(keys), depth, dtype=np.int64)
    decided = np.zeros(len(keys), dtype=bool)
    for d in range(depth + 1):
        anc = keys >> (3 * (depth - d))
        uniq, inv = np.unique(anc, return_inverse=True)
        total = np.bincount(inv, weights=counts, minlength=len(uniq))
        ok = ~decided & (total[inv] <= task_points)
        cut[ok] = d
        decided |= ok
    node = keys >> (3 * (depth - cut))
    head = np.ones(len(keys), dtype=bool)
    head[1:] = (cut[1:] != cut[:-1]) | (node[1:] != node[:-1])
    starts = np.flatnonzero(head)
    ends = np.r_[starts[1:], len(keys)]
    return [(int(cut[s]), int(node[s]), int(s), int(e)) for s, e in zip(starts, ends)]


def _chunk(records: np.ndarray, vlr) -> bytes:
    """The LAZ chunk of one node, its points in GPS time order (stable), as acquired: smaller chunks."""
    return compress(records.take(np.argsort(records["gps_time"], kind="stable")), vlr)


@dataclass(frozen=True)
class _Build:
    """What every subtree task of one export shares: the bucketed points, the octree's cube, *leaf_points*,
    the output's *header* and record *mapping*, the *scratch* folder, and the store attribute whose lowest
    value a voxel keeps (*rank*; None: its first point)."""

    store_path: str
    name: str
    origin: np.ndarray
    size: float
    leaf_points: int
    header: dict
    mapping: list
    scratch: str
    rank: str | None = None


def _subtree_task(build: _Build, runs: np.ndarray, depth: int, index: int) -> dict:
    """Build the subtree of one node at *depth* from its buckets' *runs*.

    Writes ``nodes-<index>.bin`` (a LAZ chunk per subtree node) and
    ``up-<index>.bin`` (raw ancestor records, shallowest first) to the
    scratch; returns their tables and the points' statistics.
    """
    scratch, mapping = build.scratch, build.mapping
    hdr, _ = header_from_dict(build.header)
    xyz_parts, record_parts, rank_parts = [], [], []
    # block by block: packed records and coordinates only (and the rank)
    for part in iter_runs(build.store_path, build.name, runs, _READ_BLOCK):
        xyz_parts.append(part["xyz"])
        record_parts.append(point_records(part, hdr, mapping))
        if build.rank is not None:
            rank_parts.append(part[build.rank])
        del part
    xyz, records = np.concatenate(xyz_parts), np.concatenate(record_parts)
    rank = np.concatenate(rank_parts) if build.rank is not None else None
    del xyz_parts, record_parts, rank_parts
    stats = record_stats(records, hdr.point_format)
    keys = point_keys(xyz, build.origin, build.size)
    del xyz
    # by cell at depth GRID_BITS, then input order (whatever the bucket depth)
    order = np.argsort(keys >> (3 * (KEY_DEPTH - GRID_BITS)), kind="stable")
    keys, records = keys[order], records.take(order)
    rank = None if rank is None else rank[order]
    level = assign_levels(keys, base_depth=depth, leaf_points=build.leaf_points, rank=rank)
    del rank
    order, depths, nkeys, counts = group_nodes(keys, level)
    del keys, level
    records = records.take(order)
    ends = np.cumsum(counts)
    starts = ends - counts
    vlr = laz_vlr(hdr)
    up = depths < depth
    with scratch_output(scratch, f"up-{index}.bin") as f:
        for s, e in zip(starts[up], ends[up]):
            f.write(records[s:e].tobytes())
    own = np.flatnonzero(~up)
    nbytes = np.zeros(len(own), dtype=np.int64)
    with scratch_output(scratch, f"nodes-{index}.bin") as f:
        for j, i in enumerate(own):
            chunk = _chunk(records[starts[i]:ends[i]], vlr)
            nbytes[j] = len(chunk)
            f.write(chunk)
    return {
        "up": {"depth": depths[up], "key": nkeys[up], "count": counts[up]},
        "nodes": {"depth": depths[own], "key": nkeys[own], "count": counts[own], "nbytes": nbytes},
        "stats": stats,
    }


def _ancestor_task(header: dict, scratch: str, index: int, parts: list[list[tuple[int, int, int]]]) -> np.ndarray:
    """Compress a batch of ancestor nodes from the subtree tasks' ``up`` files into ``anc-<index>.bin``.

    *parts*: per node, (task index, record offset, record count) in task
    order. The batch's nodes are consecutive in every ``up`` file, so one read
    (one ranged request) per subtree task suffices. Returns the chunks' sizes.
    """
    hdr, _ = header_from_dict(header)
    dtype = hdr.point_format.dtype()
    vlr = laz_vlr(hdr)
    spans: dict[int, tuple[int, int]] = {}  # task -> (first record, end record) read
    for node in parts:
        for task, offset, count in node:
            lo, hi = spans.get(task, (offset, offset + count))
            spans[task] = (min(lo, offset), max(hi, offset + count))
    records = {task: read_records(storage.join(scratch, f"up-{task}.bin"), lo, hi - lo, dtype)
               for task, (lo, hi) in spans.items()}
    nbytes = np.zeros(len(parts), dtype=np.int64)
    with scratch_output(scratch, f"anc-{index}.bin") as out:
        for j, node in enumerate(parts):
            pieces = [records[task][offset - spans[task][0]:offset - spans[task][0] + count]
                      for task, offset, count in node]
            chunk = _chunk(np.concatenate(pieces), vlr)
            nbytes[j] = len(chunk)
            out.write(chunk)
    return nbytes


def _bounds_task(store_path: str, mask: str, start: int, stop: int) -> np.ndarray | None:
    """Bounds ``(2, 3)`` of the points ``start:stop`` that *mask* keeps, or None when it keeps none."""
    store = PointStore.open(store_path)
    keep = store.read(mask, start, stop)
    if not keep.any():
        return None
    xyz = store.read("xyz", start, stop)[keep]
    return np.stack([xyz.min(axis=0), xyz.max(axis=0)])


def _kept_bounds(store: PointStore, mask: str, run) -> np.ndarray:
    """Bounds of the points *mask* keeps, one task per store chunk."""
    arr = store.array(mask)  # a missing mask: ArrayNotFoundError here, before any task
    if arr.ndim != 1 or arr.shape[0] != store.count or np.dtype(arr.dtype) != np.bool_:
        raise InvalidParameterError(f"{store.path}: mask {mask!r} must be a boolean array of {store.count} entries "
                                    f"(one per point), got {arr.dtype} {tuple(arr.shape)}")
    step = store.chunk_size
    parts = run(_bounds_task, [(store.path, mask, s, min(s + step, store.count))
                               for s in range(0, store.count, step)], "copc bounds")
    parts = [p for p in parts if p is not None]
    if not parts:
        return np.zeros((2, 3))
    return np.stack([np.min([p[0] for p in parts], axis=0), np.max([p[1] for p in parts], axis=0)])


def _sequential(func, args, stage):
    return [func(*a) for a in args]


def _ancestors(results: list[dict], task_points: int) -> tuple[np.ndarray, np.ndarray, list]:
    """Ancestor nodes (depth, key), in (depth, key) order, and each one's parts, batched into tasks."""
    rows = []  # (depth, key, task, offset, count)
    for t, r in enumerate(results):
        up = r["up"]
        offsets = np.cumsum(up["count"]) - up["count"]
        rows += [(int(d), int(k), t, int(o), int(c))
                 for d, k, o, c in zip(up["depth"], up["key"], offsets, up["count"])]
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    nodes: dict[tuple[int, int], list] = {}
    for d, k, t, o, c in rows:
        nodes.setdefault((d, k), []).append((t, o, c))
    batches, batch, size = [], [], 0
    for node, parts in nodes.items():
        n = sum(p[2] for p in parts)
        if batch and size + n > task_points:
            batches.append(batch)
            batch, size = [], 0
        batch.append(parts)
        size += n
    if batch:
        batches.append(batch)
    keys = np.array(list(nodes), dtype=np.int64).reshape(-1, 2)
    counts = np.array([sum(p[2] for p in parts) for parts in nodes.values()], dtype=np.int64)
    return keys, counts, batches


def export_copc(store: PointStore | str, dst: str, *, mask: str | None = None, run=None, overwrite: bool = False,
                progress=None, task_points: int = DEFAULT_TASK_POINTS,
                leaf_points: int = DEFAULT_LEAF_POINTS, rank: bool | None = None) -> dict:
    """Write the points of *store* (all, or those of the bool store array *mask*) to the COPC file *dst*.

    Every point is an exact copy of its input record (formats 6/7/8; see
    :mod:`.copc_file` for 0-5), every attribute, extra bytes, VLR and EVLR
    kept; the same bytes with any runner and worker count. *dst* is a local
    path or a URL (module docstring); *run* as :func:`.buckets.bucket`'s;
    *progress* is called with the points placed after the subtree tasks.

    Parameters
    ----------
    task_points : int
        Points per subtree task (bounds a task's memory).
    leaf_points : int
        A node holding at most this many points is a leaf; at most *task_points*.
    rank : bool, optional
        Each voxel of a node keeps its point of lowest ``cloudsieve_rank``
        (``simplify --rank``; ties by row), so the coarse levels hold the
        highest-ranked points. None (default): when the store has that
        attribute; False: the first point, as PDAL and Untwine.

    Returns
    -------
    dict
        ``{"path", "points", "nodes", "depth" (deepest node), "tasks", "bytes", "ranked"}`` (ranked: the
        voxels kept their lowest rank).

    Raises
    ------
    StoreNotFoundError, SameSourceDestinationError, DestinationExistsError,
    DestinationNotWritableError, InvalidParameterError
    """
    store, dst = source_and_destination(store, dst)
    if not (isinstance(leaf_points, (int, np.integer)) and isinstance(task_points, (int, np.integer))
            and 1 <= leaf_points <= task_points):
        raise InvalidParameterError(f"need 1 <= leaf_points <= task_points, got leaf_points={leaf_points!r}, "
                                    f"task_points={task_points!r}")
    if rank not in (None, True, False):
        raise InvalidParameterError(f"rank must be None, True or False, got {rank!r}")
    if rank and RANK_DIM not in store.dtypes:
        raise InvalidParameterError(f"{store.path} has no {RANK_DIM} attribute to order the octree by: write one "
                                    f"with cloudsieve simplify --rank")
    ranked = RANK_DIM if (rank is None and RANK_DIM in store.dtypes) or rank else None
    if ranked and not (np.dtype(store.dtypes[RANK_DIM][0]).kind in "ui" and store.dtypes[RANK_DIM][1] == ()):
        raise InvalidParameterError(f"{store.path}: {RANK_DIM} must be one integer a point, got "
                                    f"{store.dtypes[RANK_DIM][0]} {store.dtypes[RANK_DIM][1]}")
    check_destination(dst, overwrite)
    run = _sequential if run is None else run
    update = _progress.callback(progress)
    header, mapping = copc_header(store.header, store.dtypes, store.source_format, store.bounds, dst)
    origin, size = root_cube(store.bounds if mask is None else _kept_bounds(store, mask, run))
    depth = _bucket_depth(store.count, task_points)
    name = f"copc-{uuid.uuid4().hex[:12]}"
    remote = storage.is_url(dst)
    # a URL: no rename; the final task uploads dst itself, whole or not at all
    tmp = dst if remote else make_temp_path(dst)
    scratch = make_scratch(dst)
    buckets = None
    try:
        buckets = bucket(store, partial(node_keys, origin=origin, size=size, depth=depth), name, mask=mask, run=run)
        plan = _plan(buckets.keys, buckets.counts, depth, task_points)
        biggest = max((int(buckets.counts[s:e].sum()) for _, _, s, e in plan), default=0)
        if biggest > task_points:
            logger.warning("%s: a node at depth %d holds %d points, more than task_points=%d: its task holds them "
                           "all (about 165 bytes a point)", dst, depth, biggest, task_points)
        build = _Build(store.path, name, origin, size, leaf_points, header, mapping, scratch, ranked)
        args = [(build, np.concatenate([buckets.runs(int(k)) for k in buckets.keys[s:e]]), d, i)
                for i, (d, _, s, e) in enumerate(plan)]
        results = run(_subtree_task, args, "export: copc subtrees")
        for r in results:
            update(r["stats"]["count"])
        anc, anc_counts, batches = _ancestors(results, task_points)
        sizes = run(_ancestor_task, [(header, scratch, i, b) for i, b in enumerate(batches)], "export: copc ancestors")
        nodes, sources = _node_table(results, anc, anc_counts, batches, sizes, scratch)
        stats = merge_stats([r["stats"] for r in results])
        written = run(write_copc, [(tmp, header, origin, size, nodes, sources, stats)], "export: copc file")[0]
        if not remote:
            replace(tmp, dst)
    except BaseException:
        if not remote:
            remove(tmp)
        raise
    finally:
        remove_scratch(scratch)
        if buckets is not None:
            buckets.delete()
    out = {"path": dst, "points": int(stats["count"]), "nodes": len(nodes["depth"]),
           "depth": int(nodes["depth"].max()) if len(nodes["depth"]) else 0, "tasks": len(plan), "bytes": int(written),
           "ranked": ranked is not None}
    logger.info("wrote COPC %s: %d points in %d nodes (deepest %d), %d subtree tasks", dst, out["points"],
                out["nodes"], out["depth"], out["tasks"])
    return out


def _node_table(results: list[dict], anc: np.ndarray, anc_counts: np.ndarray, batches: list, sizes: list,
                scratch: str) -> tuple[dict[str, np.ndarray], list[str]]:
    """Every node (ancestors and subtrees), in (depth, Morton key) order, with its chunk's file and place."""
    sources = [storage.join(scratch, f"anc-{i}.bin") for i in range(len(batches))]
    cols: dict[str, list] = {k: [] for k in ("depth", "key", "count", "nbytes", "source", "offset")}
    batch_of = np.repeat(np.arange(len(batches)), [len(b) for b in batches])
    anc_bytes = np.concatenate(sizes) if sizes else np.empty(0, dtype=np.int64)
    cols["depth"].append(anc[:, 0])
    cols["key"].append(anc[:, 1])
    cols["count"].append(anc_counts)
    cols["nbytes"].append(anc_bytes)
    cols["source"].append(batch_of)
    cols["offset"].append(np.concatenate([np.cumsum(s) - s for s in sizes]) if sizes else np.empty(0, np.int64))
    for t, r in enumerate(results):
        own = r["nodes"]
        sources.append(storage.join(scratch, f"nodes-{t}.bin"))
        for k in ("depth", "key", "count", "nbytes"):
            cols[k].append(own[k])
        cols["source"].append(np.full(len(own["depth"]), len(sources) - 1))
        cols["offset"].append(np.cumsum(own["nbytes"]) - own["nbytes"])
    nodes = {k: np.concatenate(v).astype(np.int64) for k, v in cols.items()}
    order = np.lexsort((nodes["key"], nodes["depth"]))
    nodes = {k: v[order] for k, v in nodes.items()}
    xyz = demorton(nodes["key"])
    nodes["x"], nodes["y"], nodes["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return nodes, sources


def file_to_copc(src: str, dst: str, *, overwrite: bool = False, run=None, progress=None) -> dict:
    """Write the cloud file *src* (e.g. a ranked output of ``simplify --rank``) as the COPC file *dst*, through a
    temporary point store beside a local *dst* (else in the system's temporary folder), removed at the end.

    A ``cloudsieve_rank`` dimension orders the voxels (:func:`export_copc`, which gives the result).
    """
    import os
    import tempfile

    from .ingest import ingest

    refuse_source(os.fspath(src), dst)
    check_destination(dst, overwrite)  # before the ingest's work
    folder = tempfile.mkdtemp(prefix="cloudsieve-copc-") if storage.is_url(dst) else make_temp_path(dst, directory=True)
    try:
        store = ingest(src, os.path.join(folder, "store.zarr"), run=run)
        return export_copc(store, dst, run=run, overwrite=overwrite, progress=progress)
    finally:
        remove(folder)
