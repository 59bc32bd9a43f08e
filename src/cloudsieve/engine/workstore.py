"""The work store of a run: where it is, what it was made from, what a rerun may reuse.

When SRC is a file it is ingested into a work store, by default
``DST + ".cloudsieve.zarr"`` beside DST; that default store is deleted after
a successful run (pass ``store=`` to keep it). A run that crashed leaves it
in place, and a rerun (``resume=True``, or simply the same command) reuses
the ingest, the partition and every completed cell, after checking that the
source file (its size and mtime, recorded under ``"source"``) and the
parameters (recorded under ``"params"``) are the same
(:class:`~cloudsieve.errors.ResumeMismatchError` otherwise; ``overwrite=True``
starts again). When SRC is a store, the derived arrays are written into it.
Both records, and the run's summary, live in the store's attribute
``"cloudsieve_simplify"``.

Derived arrays of the cells stage (``simplify/``; created and deleted
through :class:`~cloudsieve.store.PointStore`)::

    keep_cells   bool    (T,)  keep mask, cell-ordered: cell j's points at
                               regions[j]:regions[j] + n_j (T: the padded total)
    score_cells  float64 (T,)  pass-1 unit-free scores (ratio/count)
    label_cells  int32   (T,)  pass-1 small-cluster labels (ratio/count); -1: an exact copy
    done, scored uint8   (P,)  one zarr chunk per cell: concurrent tasks never share one
    duplicates   int64   (P,)  exact duplicate points of each cell (one chunk per cell)
    share        float64 (P, 1 + L) eliminate: each cell's distinct points, its packing sizes (L radii)
    regions      int64   (P,)  start of each cell's region
    keep         bool    (N,)  keep mask in input order (the merge stage)

Each cell's region starts on a zarr-chunk boundary (:func:`regions`), so the
tasks of different cells never write the same chunk.
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
    "record_summary",
]

logger = logging.getLogger(__name__)

SIMPLIFY_ATTR = "cloudsieve_simplify"
ENGINE_VERSION = 1

#: columns of ``simplify/share``: a cell's distinct points, then its packing sizes
SHARE_COLUMNS = 1 + len(LADDER)


def source_identity(src: str) -> dict:
    """What identifies a source for resume: its absolute path, size and mtime (ns); for several files
    (:func:`cloudsieve.io.sources.expand_sources`) the sum of their sizes and the latest mtime."""
    from ..io.sources import expand_sources

    stats = [storage.identity(p) for p in expand_sources(src)]
    if not storage.is_url(src):
        return {"path": os.path.abspath(src) if "*" not in src else src, "size": int(sum(s for s, _ in stats)),
                "mtime_ns": int(max(int(v) for _, v in stats))}
    # objects: their ETags (or modification times) stand for the version, as one digest
    import hashlib

    digest = hashlib.sha256("\n".join(v for _, v in stats).encode()).hexdigest()[:16]
    return {"path": src, "size": int(sum(s for s, _ in stats)), "mtime_ns": digest}


def work_store_path(src: str, dst: str, store: str | os.PathLike | None, src_is_store: bool) -> str:
    """The store a run works in: SRC itself when it is a store, else *store* or ``DST + ".cloudsieve.zarr"``.

    A DST folder given with a trailing slash (``out/``) has its store beside
    it (``out.cloudsieve.zarr``), not inside. A local path is made absolute:
    workers may run elsewhere (another cwd).
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
    """The store to work in when no ingest is needed, else None.

    SRC itself when it is a store; the work store at *store_path* when it
    holds an ingest of the same source file. With *overwrite* an existing work
    store is deleted (None: ingest again).

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
    from ..store import PointStore  # zarr: imported only when a store is there

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
    """Ingest the file *src* into a new work store at *store_path* and record the source's identity.

    *drop_invalid* drops the points with NaN or infinite coordinates (see
    :func:`cloudsieve.store.ingest`) instead of refusing the file; *on_chunk*
    sees each block of points as it is stored (as in :func:`~cloudsieve.store.ingest`); *run* runs the
    tasks of a LAS source (one bar, "ingest", counting them), *bars* shows a streamed format's points.

    Returns
    -------
    PointStore
        Opened writable ("r+").
    """
    from ..store import PointStore, ingest

    from ..io.sources import expand_sources
    from ..io.las_plan import is_las_source
    from ..progress import both, stage_bar

    identity = source_identity(src)
    with stage_bar(bars, "ingest", None, "pt") as bar:  # one line, in points, whether tasks read or this process
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
    """Check the parameters of the run recorded in *store* against *params*, then record *params*.

    A store holding another run's results is refused (or, with *overwrite*,
    its derived arrays deleted); a store with no run recorded gets its derived
    arrays deleted. A summary stored by another run is dropped.

    Raises
    ------
    ResumeMismatchError
        Other parameters were recorded and *overwrite* is False.
    """
    rec = dict(store.attrs.get(SIMPLIFY_ATTR, {}))
    old = rec.get("params")
    if old is not None and old != params:
        if not overwrite:
            diff = {k: (old.get(k), params[k]) for k in params if old.get(k) != params[k]}
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

    A cell's region is padded to whole chunks (unwritten chunks take no
    space) and each chunk is a file: cell_size / 4 writes a cell's keep
    mask in about 7 files, where cell_size / 16 writes 27, each a file's
    cost. A store on object storage (*remote*), where each object is a
    request: a power of two at least cell_size, in [2^10, 2^20] (most
    regions one object).
    """
    if remote:
        return 1 << max(10, min(20, math.ceil(math.log2(max(1, cell_size)))))
    return 1 << max(10, min(16, int(math.log2(max(1, cell_size // 4)))))


def regions(cell_counts: np.ndarray, block: int) -> tuple[np.ndarray, int]:
    """Start of each cell's region in the cell-ordered arrays, aligned to *block*.

    Returns
    -------
    starts : ndarray of shape (P,), int64
    total : int
        Length of the cell-ordered arrays (at least *block*).
    """
    padded = -(-cell_counts // block) * block
    padded = np.maximum(padded, 0)
    starts = np.zeros(len(cell_counts), dtype=np.int64)
    np.cumsum(padded[:-1], out=starts[1:])
    total = int(padded.sum())
    return starts, max(total, block)


def ensure_cell_arrays(store, n_cells: int, total: int, block: int, starts: np.ndarray, band_block: int = 0) -> None:
    """Create the cell-ordered ``simplify/*`` arrays unless they exist with this layout (a resumed run); the
    bands in chunks of *band_block* (a divisor of *block*; default *block*: a band is a region's start)."""
    band_block = band_block or block
    g = store.group
    # the same layout: length, chunk and regions (a store of a version with another chunk starts again)
    same = ("simplify/keep_cells" in g and "simplify/regions" in g and g["simplify/keep_cells"].shape == (total,)
            and tuple(g["simplify/keep_cells"].chunks) == (block,)
            and np.array_equal(np.asarray(g["simplify/regions"][:]), np.asarray(starts, dtype=np.int64)))
    if same:
        if "simplify/duplicates" not in g:  # a store of a version before the count (its done cells count 0)
            store.create_array("simplify/duplicates", shape=(n_cells,), dtype="int64", chunks=(1,), fill_value=0)
        if "simplify/share" not in g or g["simplify/share"].shape != (n_cells, SHARE_COLUMNS):
            # a store of a version before the shares or the packings: its cells start again
            store.delete_array("simplify/share")
            _share_array(store, n_cells)
            g["simplify/scored"][:] = np.zeros(n_cells, dtype=np.uint8)
            g["simplify/done"][:] = np.zeros(n_cells, dtype=np.uint8)
        if "simplify/band_count" not in g:  # a store of a version before the bands: its cells start again
            _band_arrays(store, n_cells, total, band_block)
            g["simplify/scored"][:] = np.zeros(n_cells, dtype=np.uint8)
            g["simplify/done"][:] = np.zeros(n_cells, dtype=np.uint8)
        return
    for name in ("keep_cells", "score_cells", "label_cells", "done", "scored", "keep", "regions", "duplicates",
                 "share", "band_xyz", "band_pos", "band_count"):
        store.delete_array(f"simplify/{name}")
    store.create_array("simplify/keep_cells", shape=(total,), dtype="bool", chunks=(block,), fill_value=False)
    store.create_array("simplify/done", shape=(n_cells,), dtype="uint8", chunks=(1,), fill_value=0)
    store.create_array("simplify/score_cells", shape=(total,), dtype="float64", chunks=(block,), fill_value=0.0)
    store.create_array("simplify/label_cells", shape=(total,), dtype="int32", chunks=(block,), fill_value=0)
    store.create_array("simplify/scored", shape=(n_cells,), dtype="uint8", chunks=(1,), fill_value=0)
    _share_array(store, n_cells)
    _band_arrays(store, n_cells, total, band_block)
    # exact duplicate points of each cell (written with done)
    store.create_array("simplify/duplicates", shape=(n_cells,), dtype="int64", chunks=(1,), fill_value=0)
    # start of each cell's region, read by the merge tasks (P numbers: not passed to every task)
    store.create_array(
        "simplify/regions", data=np.asarray(starts, dtype=np.int64), chunks=(max(1, min(len(starts), 65536)),)
    )


def _share_array(store, n_cells: int) -> None:
    """eliminate: each cell's distinct points and packing sizes (:func:`cloudsieve.core.packing.packing_ladder`)."""
    store.create_array("simplify/share", shape=(n_cells, SHARE_COLUMNS), dtype="float64", chunks=(1, SHARE_COLUMNS),
                       fill_value=0.0)


def _band_arrays(store, n_cells: int, total: int, block: int) -> None:
    """eliminate: each cell's band (:func:`cloudsieve.engine.halo.band_mask`) at the start of its region."""
    store.create_array("simplify/band_xyz", shape=(total, 3), dtype="float64", chunks=(block, 3), fill_value=0.0)
    store.create_array("simplify/band_pos", shape=(total,), dtype="int64", chunks=(block,), fill_value=0)
    store.create_array("simplify/band_count", shape=(n_cells,), dtype="int64", chunks=(1,), fill_value=0)


def ensure_keep_array(store) -> None:
    """Create ``simplify/keep`` (input order, one zarr chunk per input chunk) unless it exists."""
    if "simplify/keep" not in store:
        store.create_array(
            "simplify/keep", shape=(store.count,), dtype="bool", chunks=(store.chunk_size,), fill_value=False
        )
