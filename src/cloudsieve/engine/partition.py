"""Stage 2, partition: P = ceil(N / cell_size) coarse K-means cells, bucketed out of core, with halos.

A seeded uniform sample (:mod:`.sample`), P centres by
:class:`~cloudsieve.core.KMeans` on it, one label-and-bucket task per input
chunk (:mod:`.label`), and the run tables (:mod:`.runs`). Layout under ``partition/``::

    centers     float64 (P, 3)           cell centres (absolute coordinates)
    cell        int32   (N,)             cell of every point, input order
    xyz         float64 (n_chunks, R, 3) row c: chunk c's points sorted by cell (stable),
                                         one shard per row (int32 for LAS integers)
    chunk_ptr, chunk_runs, cell_ptr,     the run tables and points per cell (:mod:`.runs`)
    cell_runs, cell_count
    halo_ptr, halo_src                   CSR: for cell i, the cells that may hold its halo

The halo (:mod:`cloudsieve.engine.halo`) is the points of other cells within
``margin``: ``HALO_RADII`` k-NN radii estimated on the sample, and for the
eliminate rule at least ``ELIMINATE_RADII`` r_max
(:func:`cloudsieve.core.radius.global_radius`).
"""

from __future__ import annotations

import logging
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..core import neighbour_count
from ..errors import PartitionLayoutError
from ..paths import local_path
from .label import label_chunk
from .runs import cell_runs, chunk_runs, index_runs
from .sample import IngestSample, n_cells_for, plan_sample, sample_chunk, sample_size  # noqa: F401 - re-exported

__all__ = [
    "Partition",
    "PARTITION_ATTR",
    "PARTITION_VERSION",
    "PartitionLayoutError",
    "plan_sample",
    "sample_chunk",
    "IngestSample",
    "fit_centers",
    "estimate_margin",
    "fit_sample",
    "halo_lists",
    "build_partition",
    "reusable_partition",
]

logger = logging.getLogger(__name__)

PARTITION_ATTR = "cloudsieve_partition"
PARTITION_VERSION = 3
#: halo margin, in k-NN radii of the full-density cloud
HALO_RADII = 3.0
#: halo margin of the eliminate rule, in elimination radii r_max (its reach is 2 r_max)
ELIMINATE_RADII = 2.2
#: inner chunk of the sharded ``partition/xyz`` rows, in points (REMOTE_INNER_CHUNK on object storage)
INNER_CHUNK = 16384
REMOTE_INNER_CHUNK = 65536


def fit_centers(sample: np.ndarray, n_cells: int, seed: int, origin: np.ndarray) -> np.ndarray:
    """P centres by K-means on the sample (relative to *origin*): (n_cells, 3) float64, absolute.

    Sorted lexicographically (x, y, z) so cell ids do not depend on the K-means initialisation.
    """
    rel = sample - origin
    if n_cells <= 1:
        centers = rel.mean(axis=0, keepdims=True) if len(rel) else np.zeros((1, 3))
    else:
        from ..core import KMeans  # here: one cell needs no K-means (nor its modules' import)

        km = KMeans(n_clusters=n_cells, seed=int(seed)).fit(rel)
        centers = np.asarray(km.cluster_centers_, dtype=np.float64)
    centers = centers + origin
    order = np.lexsort((centers[:, 2], centers[:, 1], centers[:, 0]))
    return np.ascontiguousarray(centers[order])


def estimate_margin(sample: np.ndarray, n_total: int, k: int, seed: int) -> tuple[float, float, float]:
    """``(r_k, dimension, margin)``: the full cloud's k-NN radius estimated on the sample, and the halo margin.

    Median k-th neighbour distances at sample sizes S and S/8 give the
    intrinsic dimension d (clipped to [1, 3]); ``r_full = r_S * (S / N) ** (1 / d)``.
    """
    s = len(sample)
    if s < 16 * (k + 2):
        if s < 2:
            return 0.0, 3.0, 0.0
        ext = np.ptp(sample, axis=0).max()
        r = float(ext) * (k / max(n_total, 1)) ** (1 / 3)
        return r, 3.0, HALO_RADII * r
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x3A21]))
    perm = rng.permutation(s)
    rel = sample - sample.mean(axis=0)
    q = rel[perm[: min(s, 4000)]]
    sub = rel[perm[: s // 8]]
    from scipy.spatial import cKDTree  # here: its import costs a small run more than its work

    r1 = float(np.median(cKDTree(rel).query(q, k=k + 1)[0][:, k]))
    r2 = float(np.median(cKDTree(sub).query(q, k=k + 1)[0][:, k]))
    if r1 > 0 and r2 > r1:
        d = float(np.clip(math.log(8.0) / math.log(r2 / r1), 1.0, 3.0))
    else:
        d = 3.0
    r = r1 * (s / max(n_total, 1)) ** (1.0 / d)
    return r, d, HALO_RADII * r


@dataclass
class Partition:
    """The partition of a store, read back from ``partition/`` (arrays of size P only).

    ``halo_src[halo_ptr[i]:halo_ptr[i+1]]`` are the cells that may hold halo
    points of cell i; *r_max* is the eliminate rule's global radius (inf:
    every point kept; None for other rules); *group* is the store's group,
    from which the run tables are read on demand.
    """

    centers: np.ndarray
    cell_counts: np.ndarray
    halo_ptr: np.ndarray
    halo_src: np.ndarray
    margin: float
    chunk_size: int
    n_chunks: int
    n_runs: int
    r_max: float | None = None
    group: object = field(repr=False, default=None)

    @property
    def n_cells(self) -> int:
        return len(self.centers)

    def runs(self, cell: int) -> np.ndarray:
        """The runs of *cell*: see :func:`cell_runs`."""
        return cell_runs(self.group, cell)

    def chunk_runs(self, chunk: int) -> np.ndarray:
        """The runs of input chunk *chunk*: see :func:`chunk_runs`."""
        return chunk_runs(self.group, chunk)

    def halo_sources(self, cell: int) -> np.ndarray:
        return self.halo_src[self.halo_ptr[cell] : self.halo_ptr[cell + 1]]

    @classmethod
    def load(cls, store) -> Partition:
        """Read the partition recorded in *store*.

        Raises
        ------
        PartitionLayoutError
            No complete partition, or one in another layout: partition again.
        """
        g = store.group
        meta = store.attrs.get(PARTITION_ATTR)
        if not isinstance(meta, dict) or not meta.get("complete"):
            raise PartitionLayoutError(f"{store.path} holds no complete partition: partition it again")
        if meta.get("version") != PARTITION_VERSION:
            raise PartitionLayoutError(
                f"{store.path} holds a partition in layout version {meta.get('version')}, this cloudsieve reads "
                f"version {PARTITION_VERSION}: partition it again (simplify does so by itself)"
            )
        return cls(
            centers=np.asarray(g["partition/centers"][:]),
            cell_counts=np.asarray(g["partition/cell_count"][:]).astype(np.int64),
            halo_ptr=np.asarray(g["partition/halo_ptr"][:]),
            halo_src=np.asarray(g["partition/halo_src"][:]),
            margin=float(meta["margin"]),
            chunk_size=int(meta["chunk_size"]),
            n_chunks=int(meta["n_chunks"]),
            n_runs=int(meta["n_runs"]),
            r_max=None if meta.get("r_max") is None else float(meta["r_max"]),
            group=g,
        )


def row_layout(chunk_size: int, remote: bool = False) -> tuple[int, int]:
    """(R, inner): a ``partition/xyz`` row holds R >= chunk_size points in inner chunks (larger when *remote*)."""
    inner = min(REMOTE_INNER_CHUNK if remote else INNER_CHUNK, chunk_size)
    return -(-chunk_size // inner) * inner, inner


def fit_sample(sample: np.ndarray, n: int, n_cells: int, seed: int, origin: np.ndarray, k: int,
               eliminate_target: int | None) -> tuple[np.ndarray, tuple[float, float, float], float | None]:
    """Centres, ``(r_k, dimension, margin)`` (zeros for one cell) and r_max (None without *eliminate_target*).

    The K-means runs on a second thread beside the margin and r_max."""
    with ThreadPoolExecutor(1) as side:
        centers = side.submit(fit_centers, sample, n_cells, seed, origin)
        if n_cells > 1:
            r_k, dim, margin = estimate_margin(sample - origin, n, k, seed)
        else:  # no margin to estimate (and no scipy.spatial to import)
            r_k, dim, margin = 0.0, 3.0, 0.0
        r_max = None
        if eliminate_target is not None:
            from ..core.radius import global_radius

            r_max = global_radius(sample, n, int(eliminate_target))
            if math.isfinite(r_max):
                margin = max(margin, ELIMINATE_RADII * r_max)
        return centers.result(), (r_k, dim, margin), r_max


def halo_lists(pairs: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """The halo CSR (``halo_ptr`` (P + 1,), ``halo_src`` (h,), int64) of (cell, source) *pairs* sorted by row."""
    halo_ptr = np.zeros(n_cells + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=n_cells), out=halo_ptr[1:])
    return halo_ptr, pairs[:, 1].astype(np.int64)


def build_partition(
    store, *, cell_size: int, cluster_size: int, seed: int, run, k0: float = 1.0, k_min: int = 4, halo: bool = True,
    eliminate_target: int | None = None, sample: np.ndarray | None = None,
) -> Partition:
    """Partition *store* (opened "r+") into P = ceil(N / cell_size) cells and record it in the store.

    *cluster_size* sets the halo's k; *run* is the engine's runner; *halo*
    lists every cell's halo sources (for a density context; False labels
    faster); *eliminate_target*, the kept count of an ``eliminate`` run, has
    r_max solved and recorded; *sample*: the ingest's
    (:meth:`IngestSample.sample`), else read from the store.
    """
    n = store.count
    chunk = store.chunk_size
    p = n_cells_for(n, cell_size)
    starts = list(range(0, n, chunk))
    n_chunks = len(starts)
    path = store.path

    if sample is None:  # read from the store (else taken by the ingest: IngestSample)
        idx = plan_sample(n, p, seed)
        bounds = np.searchsorted(idx, [min(s + chunk, n) for s in starts])
        lo = np.concatenate([[0], bounds[:-1]])
        args = [(path, s, min(s + chunk, n), idx[a:b]) for s, a, b in zip(starts, lo, bounds)]
        parts = run(sample_chunk, args, "partition: sample")
        sample = np.concatenate(parts, axis=0) if parts else np.empty((0, 3))
    origin = np.asarray(store.bounds[0], dtype=np.float64)
    k = int(neighbour_count(cluster_size, k0, k_min))  # the core's one k formula
    # a task: the K-means, the margin and r_max (their imports and compiled kernels) are no driver work
    fitted = run(fit_sample, [(sample, n, p, seed, origin, k, eliminate_target)], "partition: fit")
    centers, (r_k, dim, margin), r_max = fitted[0]
    if r_max is not None:
        logger.info("partition: eliminate %d of %d points, r_max %.4g, margin %.4g", eliminate_target, n, r_max,
                    margin)
    logger.info("partition: %d points -> %d cells, sample %d, r_%d=%.4g (d=%.2f), margin %.4g", n, p, len(sample), k, r_k, dim, margin)

    store.delete_arrays([f"partition/{name}" for name in ("cell", "counts", "xyz", "centers", "halo_ptr", "halo_src",
                         "label_runs", "chunk_ptr", "chunk_runs", "cell_ptr", "cell_runs", "cell_count")])
    store.create_array("partition/centers", data=centers, chunks=centers.shape)
    store.create_array("partition/cell", shape=(n,), dtype="int32", chunks=(chunk,), fill_value=-1)
    r_len, inner = row_layout(chunk, local_path(path) is None)
    store.create_array(
        "partition/xyz", shape=(n_chunks, r_len, 3), dtype="float64" if store.xyz_scale is None else "int32",
        chunks=(1, inner, 3), shards=(1, r_len, 3)
    )
    # scratch: row c holds chunk c's nonzero runs; only the written zarr chunks are stored
    width = max(1, min(chunk, p))
    store.create_array("partition/label_runs", shape=(n_chunks, width, 2), dtype="int64", chunks=(1, min(width, 4096), 2))
    args = [(path, c, s, min(s + chunk, n), margin, bool(halo)) for c, s in enumerate(starts)]
    results = run(label_chunk, args, "partition: label")
    pair_lists = [r[0] for r in results]
    nnz = np.array([r[1] for r in results], dtype=np.int64)
    pairs = np.unique(np.concatenate(pair_lists, axis=0), axis=0) if pair_lists else np.empty((0, 2), np.int64)
    halo_ptr, halo_src = halo_lists(pairs, p)
    index_runs(store, nnz, p, chunk)
    store.create_array("partition/halo_ptr", data=halo_ptr, chunks=halo_ptr.shape)
    store.create_array("partition/halo_src", data=halo_src, chunks=(max(1, len(halo_src)),))
    meta = {
        "version": PARTITION_VERSION,
        "cell_size": int(cell_size),
        "cluster_size": int(cluster_size),
        "seed": int(seed),
        "count": int(n),
        "chunk_size": int(chunk),
        "n_cells": int(p),
        "n_chunks": int(n_chunks),
        "n_runs": int(nnz.sum()),
        "halo": bool(halo),
        "sample": int(len(sample)),
        "k": k,
        "r_k": r_k,
        "dimension": dim,
        "margin": margin,
        "eliminate_target": None if eliminate_target is None else int(eliminate_target),
        "r_max": None if r_max is None else (float(r_max) if math.isfinite(r_max) else "inf"),
        "complete": True,
    }
    store.group.attrs.update({PARTITION_ATTR: meta})
    return Partition.load(store)


def reusable_partition(store, *, cell_size: int, cluster_size: int, seed: int, halo: bool,
                       eliminate_target: int | None = None) -> Partition | None:
    """The partition in *store* if a run with these parameters can reuse it, else None.

    Requires a complete partition in this layout, the same cell size,
    cluster size, seed and *eliminate_target*, and halo sources if *halo*.
    """
    meta = store.attrs.get(PARTITION_ATTR)
    want = {"cell_size": int(cell_size), "cluster_size": int(cluster_size), "seed": int(seed),
            "eliminate_target": None if eliminate_target is None else int(eliminate_target)}
    complete = isinstance(meta, dict) and meta.get("complete")
    if complete and meta.get("version") != PARTITION_VERSION:
        # an older layout: rebuilt, with the cells
        logger.info(
            "the partition in %s has layout version %s (this version writes %d): partitioning again",
            store.path, meta.get("version"), PARTITION_VERSION,
        )
        return None
    if complete and all(meta.get(k) == v for k, v in want.items()) and (meta.get("halo") or not halo):
        part = Partition.load(store)
        logger.info("reusing the partition in %s (%d cells)", store.path, part.n_cells)
        return part
    return None
