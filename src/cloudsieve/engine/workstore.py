"""The work store of a run: where it is, what it was made from, what a rerun may reuse.

A file SRC is ingested into a work store (default ``DST + ".cloudsieve.zarr"``,
deleted after success); a rerun reuses its ingest, partition and done cells
when the source and parameters match, both recorded in the attribute
``"cloudsieve_simplify"``. Derived arrays (``simplify/``)::

    keep_cells   bool    (T,)  keep mask, cell-ordered: cell j at regions[j]:regions[j] + n_j
    fill_cells   bool    (T,)  the gap bound's fill (max_gap only), cell-ordered
    score_cells  float64 (T,)  pass-1 unit-free scores (ratio/count)
    label_cells  int32   (T,)  pass-1 small-cluster labels; -1: an exact copy
    done, scored uint8   (P,)  one zarr chunk per cell
    duplicates   int64   (P,)  exact duplicates of each cell
    share        float64 (P, 1 + L) eliminate: distinct points, packing sizes
                         (P, 1 + G (1 + L)) with class policies: points kept whole, then per group
    group_cells  int8    (T,)  eliminate with class policies: each point's group, -1 kept whole
    regions      int64   (P,)  start of each cell's region, on a zarr-chunk boundary
    keep         bool    (N,)  keep mask in input order (merge)
"""

from __future__ import annotations

import logging
import math
import os


import numpy as np

from .. import storage
from ..core.packing import LADDER
from ..errors import ResumeMismatchError
from ..store import delete_store, is_store

__all__ = [
    "SIMPLIFY_ATTR",
    "ENGINE_VERSION",
    "source_identity",
    "work_store_path",
    "reusable_store",
    "ingest_source",
    "record_params",
    "clear_derived",
    "region_block",
    "regions",
    "ensure_cell_arrays",
    "ensure_keep_array",
    "ensure_fill_array",
    "record_summary",
]

logger = logging.getLogger(__name__)

SIMPLIFY_ATTR = "cloudsieve_simplify"
ENGINE_VERSION = 1

#: columns of ``simplify/share``: a cell's distinct points, then its packing sizes
SHARE_COLUMNS = 1 + len(LADDER)


def source_identity(src: str) -> dict:
    """A source's identity for resume: absolute path, size and mtime (ns); several files sum
    sizes and take the latest mtime; objects a digest of their versions."""
    from ..io.sources import expand_sources

    stats = [storage.identity(p) for p in expand_sources(src)]
    if not storage.is_url(src):
        return {"path": os.path.abspath(src) if "*" not in src else src, "size": int(sum(s for s, _ in stats)),
                "mtime_ns": int(max(int(v) for _, v in stats))}
    # objects: their ETags (or modification times), as one digest
    import hashlib

    digest = hashlib.sha256("\n".join(v for _, v in stats).encode()).hexdigest()[:16]
    return {"path": src, "size": int(sum(s for s, _ in stats)), "mtime_ns": digest}


def work_store_path(src: str, dst: str, store: str | os.PathLike | None, src_is_store: bool) -> str:
    """The store a run works in: SRC when it is a store, else *store* or ``DST + ".cloudsieve.zarr"``.

    ``out/`` puts it beside the folder; a local path is made absolute (workers may have another cwd).
    """
    if src_is_store:
        path = src
    else:
        folder = dst.rstrip("/") if len(dst) > 1 else dst
        path = os.fspath(store) if store is not None else folder + ".cloudsieve.zarr"
    if "://" not in path:
        path = os.path.abspath(path)
    return path


def reusable_store(src: str, store_path: str, *, src_is_store: bool, overwrite: bool, resume: bool):
    """The store to work in when no ingest is needed (SRC itself, or a work store of the same source), else None.

    With *overwrite* an existing work store is deleted.

    Raises
    ------
    ResumeMismatchError
        The work store was ingested from another file (or the file changed).
    """
    if src_is_store:
        from ..store import PointStore

        return PointStore.open(store_path, "r+")
    identity = source_identity(src)
    existing = is_store(store_path)
    if existing and overwrite:
        delete_store(store_path)
        existing = False
    if resume and not existing:
        logger.info("resume: no complete work store at %s, starting from the ingest", store_path)
    if not existing:
        return None
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    rec = st.attrs.get(SIMPLIFY_ATTR, {}).get("source")
    if rec is not None and (rec["size"], rec["mtime_ns"]) != (identity["size"], identity["mtime_ns"]):
        raise ResumeMismatchError(
            f"work store {store_path} was ingested from {rec['path']} "
            f"({rec['size']} bytes, mtime {rec['mtime_ns']}), not from {src} "
            f"({identity['size']} bytes, mtime {identity['mtime_ns']}); pass overwrite=True to start again",
            advice={"overwrite": True},
        )
    logger.info("reusing the ingest in %s", store_path)
    return st


def ingest_source(src: str, store_path: str, *, chunk_size: int, progress=None, drop_invalid: bool = False,
                  on_chunk=None, run=None, bars=None):
    """Ingest the file *src* into a new work store at *store_path*, record the source's identity, open it "r+".

    *drop_invalid* and *on_chunk* are :func:`cloudsieve.store.ingest`'s;
    *run* runs a LAS source's tasks; *bars* shows one "ingest" bar in points.
    """
    from ..store import PointStore, ingest

    from ..io.sources import expand_sources
    from ..io.las_plan import is_las_source
    from ..progress import both, stage_bar

    identity = source_identity(src)
    with stage_bar(bars, "ingest", None, "pt") as bar:
        update = both(bar, progress)
        if is_las_source(expand_sources(src)):
            ingest.unchecked(src, store_path, chunk_size=chunk_size, overwrite=True, progress=update, run=run)
        else:
            ingest.unchecked(src, store_path, chunk_size=chunk_size, overwrite=True, progress=update,
                             drop_invalid=drop_invalid, on_chunk=on_chunk)
    st = PointStore.open(store_path, "r+")
    st.group.attrs.update({SIMPLIFY_ATTR: {"source": identity}})
    return st


def record_params(store, params: dict, overwrite: bool) -> None:
    """Check the run recorded in *store* against *params*, then record *params*.

    Another run's store is refused, or with *overwrite* its derived arrays
    deleted; so are those of a store with no run recorded. A stored summary
    is dropped.

    Raises
    ------
    ResumeMismatchError
        Other parameters were recorded and *overwrite* is False.
    """
    rec = dict(store.attrs.get(SIMPLIFY_ATTR, {}))
    old = rec.get("params")
    if old is not None and old != params:
        if not overwrite:
            names = [*params, *(k for k in old if k not in params)]  # a recorded option this run lacks too
            diff = {k: (old.get(k), params.get(k)) for k in names if old.get(k) != params.get(k)}
            raise ResumeMismatchError(
                f"store {store.path} holds a run with other parameters "
                + ", ".join(f"{k}: stored {a!r}, asked {b!r}" for k, (a, b) in diff.items())
                + "; pass overwrite=True to discard it",
                advice={"overwrite": True},
            )
        old = None
    if old is None:
        clear_derived(store)
    rec["params"] = params
    rec.pop("summary", None)
    store.group.attrs.update({SIMPLIFY_ATTR: rec})


def record_summary(store, summary: dict) -> None:
    """Store a run's summary (``Summary.to_dict()``) beside its parameters."""
    rec = dict(store.attrs.get(SIMPLIFY_ATTR, {}))
    rec["summary"] = summary
    store.group.attrs.update({SIMPLIFY_ATTR: rec})


def clear_derived(store) -> None:
    """Delete the simplify arrays (they depend on the partition and the parameters)."""
    store.delete_array("simplify")


def region_block(cell_size: int, remote: bool = False) -> int:
    """zarr chunk of the cell-ordered arrays: a power of two near cell_size / 4, in [2^10, 2^16].

    Regions are padded to whole chunks, each a file: fewer, larger files per
    cell. *remote* (each object a request): at least cell_size, in [2^10, 2^20].
    """
    if remote:
        return 1 << max(10, min(20, math.ceil(math.log2(max(1, cell_size)))))
    return 1 << max(10, min(16, int(math.log2(max(1, cell_size // 4)))))


def regions(cell_counts: np.ndarray, block: int) -> tuple[np.ndarray, int]:
    """Start (P,) int64 of each cell's region in the cell-ordered arrays, aligned to *block*, and their length."""
    padded = -(-cell_counts // block) * block
    padded = np.maximum(padded, 0)
    starts = np.zeros(len(cell_counts), dtype=np.int64)
    np.cumsum(padded[:-1], out=starts[1:])
    total = int(padded.sum())
    return starts, max(total, block)


def ensure_cell_arrays(store, n_cells: int, total: int, block: int, starts: np.ndarray, band_block: int = 0,
                       groups: int = 0) -> None:
    """Create the cell-ordered ``simplify/*`` arrays unless they exist with this layout (resume); bands in
    chunks of *band_block* (a divisor of *block*; default *block*); with class policies of *groups* groups
    (:mod:`.class_cells`), ``share`` holds the points kept whole and a share per group, and
    ``group_cells`` (T,) int8 each point's group."""
    band_block = band_block or block
    columns = 1 + groups * SHARE_COLUMNS if groups else SHARE_COLUMNS
    g = store.group
    # the same layout: length, chunk and regions (another layout starts again)
    same = ("simplify/keep_cells" in g and "simplify/regions" in g and g["simplify/keep_cells"].shape == (total,)
            and tuple(g["simplify/keep_cells"].chunks) == (block,)
            and np.array_equal(np.asarray(g["simplify/regions"][:]), np.asarray(starts, dtype=np.int64)))
    if same:
        if "simplify/duplicates" not in g:  # an older store: its done cells count 0
            store.create_array("simplify/duplicates", shape=(n_cells,), dtype="int64", chunks=(1,), fill_value=0)
        if ("simplify/share" not in g or g["simplify/share"].shape != (n_cells, columns)
                or groups and "simplify/group_cells" not in g):
            # an older store without shares or packings, or other groups: its cells start again
            store.delete_array("simplify/share")
            _share_array(store, n_cells, columns)
            _group_array(store, total, block, groups)
            g["simplify/scored"][:] = np.zeros(n_cells, dtype=np.uint8)
            g["simplify/done"][:] = np.zeros(n_cells, dtype=np.uint8)
        if "simplify/band_count" not in g:  # an older store without bands: its cells start again
            _band_arrays(store, n_cells, total, band_block)
            g["simplify/scored"][:] = np.zeros(n_cells, dtype=np.uint8)
            g["simplify/done"][:] = np.zeros(n_cells, dtype=np.uint8)
        return
    store.delete_arrays([f"simplify/{name}" for name in (
        "keep_cells", "fill_cells", "score_cells", "label_cells", "done", "scored", "keep", "regions", "duplicates",
        "share", "band_xyz", "band_pos", "band_count", "group_cells")])
    store.create_array("simplify/keep_cells", shape=(total,), dtype="bool", chunks=(block,), fill_value=False)
    store.create_array("simplify/done", shape=(n_cells,), dtype="uint8", chunks=(1,), fill_value=0)
    store.create_array("simplify/score_cells", shape=(total,), dtype="float64", chunks=(block,), fill_value=0.0)
    store.create_array("simplify/label_cells", shape=(total,), dtype="int32", chunks=(block,), fill_value=0)
    store.create_array("simplify/scored", shape=(n_cells,), dtype="uint8", chunks=(1,), fill_value=0)
    _share_array(store, n_cells, columns)
    _group_array(store, total, block, groups)
    _band_arrays(store, n_cells, total, band_block)
    # exact duplicates of each cell (written with done)
    store.create_array("simplify/duplicates", shape=(n_cells,), dtype="int64", chunks=(1,), fill_value=0)
    # region starts, read by the merge tasks (not passed to every task)
    store.create_array(
        "simplify/regions", data=np.asarray(starts, dtype=np.int64), chunks=(max(1, min(len(starts), 65536)),)
    )


def _share_array(store, n_cells: int, columns: int = SHARE_COLUMNS) -> None:
    """eliminate: each cell's distinct points and packing sizes (:func:`cloudsieve.core.packing.packing_ladder`)."""
    store.create_array("simplify/share", shape=(n_cells, columns), dtype="float64", chunks=(1, columns),
                       fill_value=0.0)


def _group_array(store, total: int, block: int, groups: int) -> None:
    """eliminate with class policies: each point's group, cell-ordered (none without policies)."""
    store.delete_array("simplify/group_cells")
    if groups:
        store.create_array("simplify/group_cells", shape=(total,), dtype="int8", chunks=(block,), fill_value=0)


def _band_arrays(store, n_cells: int, total: int, block: int) -> None:
    """eliminate: each cell's band (:func:`cloudsieve.engine.halo.band_mask`) at the start of its region."""
    store.create_array("simplify/band_xyz", shape=(total, 3), dtype="float64", chunks=(block, 3), fill_value=0.0)
    store.create_array("simplify/band_pos", shape=(total,), dtype="int64", chunks=(block,), fill_value=0)
    store.create_array("simplify/band_count", shape=(n_cells,), dtype="int64", chunks=(1,), fill_value=0)


def ensure_fill_array(store) -> None:
    """Create ``simplify/fill_cells`` (the gap bound's fill, as ``keep_cells``) unless it exists."""
    if "simplify/fill_cells" not in store:
        kc = store.group["simplify/keep_cells"]
        store.create_array("simplify/fill_cells", shape=kc.shape, dtype="bool", chunks=kc.chunks, fill_value=False)


def ensure_keep_array(store) -> None:
    """Create ``simplify/keep`` (input order, one zarr chunk per input chunk) unless it exists."""
    if "simplify/keep" not in store:
        store.create_array(
            "simplify/keep", shape=(store.count,), dtype="bool", chunks=(store.chunk_size,), fill_value=False
        )
