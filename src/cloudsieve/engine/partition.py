"""Stage 2, partition: coarse spatial K-means cells, bucketed out of core, with halos.

A store of N points is cut into P = ceil(N / cell_size) cells:

1. **sample** -- a uniform sample of S points (indices drawn once from the seed,
   so the sample does not depend on the store's chunking), read chunk by chunk;
2. **fit** -- P centres by the core :class:`~cloudsieve.cluster.KMeans` on the
   sample (coordinates taken relative to the store's lower bound);
3. **label + bucket** -- one task per input chunk labels its points with the
   nearest centre (k-d tree over the centres, exact ties to the lower index),
   sorts them by cell *inside the chunk* (stable) and writes the sorted copy to
   its own row of ``partition/xyz``. Nothing is written to another task's
   zarr chunk, nothing is ever sorted globally.

Layout written into the store (all under ``partition/``)::

    centers     float64 (P, 3)          cell centres (absolute coordinates)
    cell        int32   (N,)            cell of every point, input order
    cell_count  int64   (P,)            points per cell
    xyz         float64 (n_chunks, R, 3) row c: chunk c's points sorted by cell
                                         (stable), R = chunk size rounded up to the
                                         inner chunk; sharded, one shard per row,
                                         so a slice reads only the inner chunks it
                                         touches
    chunk_ptr   int64   (n_chunks + 1,) CSR by chunk: the runs of chunk c are
    chunk_runs  int64   (nnz, 3)          chunk_runs[chunk_ptr[c]:chunk_ptr[c + 1]],
                                         rows (cell, count, first), cells increasing;
                                         first = points of that cell in chunks < c
    cell_ptr    int64   (P + 1,)        CSR by cell: the runs of cell j are
    cell_runs   int64   (nnz, 3)          cell_runs[cell_ptr[j]:cell_ptr[j + 1]],
                                         rows (chunk, start, count), chunks increasing;
                                         the points are xyz[chunk, start:start + count]
    halo_ptr, halo_src                   CSR: for cell i, the cells that may hold
                                         points of i's halo

Only the nonzero (chunk, cell) runs are stored (nnz of them, at most
min(N, n_chunks * P) and about n_chunks + P for a spatially coherent input), so
nothing of size n_chunks x P exists anywhere: a cell task reads its own runs
(:func:`cell_runs`), a merge task its chunk's (:func:`chunk_runs`), and the
driver holds arrays of size P or n_chunks only (the run tables are built by
streaming, see :func:`index_runs`).

This is a two-level CSR: the points of cell j are, in input order, its runs
``xyz[c, start:start + count]``. ``xyz`` is written in one pass with
chunk-aligned, conflict-free writes (concurrent tasks never share a zarr chunk),
and read back with one small sharded slice per run. The order of a cell's
points is increasing input index, whatever the scheduler.

Halo: a point z of cell j lies in the halo of cell i when its distance to the
bisector plane of c_i and c_j is at most ``margin``::

    s_ij(z) = (z - (c_i + c_j) / 2) . (c_j - c_i) / |c_j - c_i|  <=  margin

Since the Voronoi region of i lies on c_i's side of that plane, every point
within ``margin`` of cell i's region passes (the test is a safe superset).
``margin`` is a few k-NN radii (``HALO_RADII`` times r_k, k the entropy
neighbourhood size of a cluster of ``cluster_size`` points), r_k estimated on
the sample and scaled to full density with the sample's intrinsic dimension.
The label pass records, from each point's ``HALO_NEIGHBOURS`` nearest centres,
which cells can contribute to which halos (``halo_ptr``/``halo_src``); a cell
task reads those cells' runs and applies the test itself (see
:func:`read_halo`). Halo points are density context only, never pruned.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..errors import PartitionLayoutError

__all__ = [
    "Partition",
    "PARTITION_ATTR",
    "plan_sample",
    "sample_chunk",
    "fit_centers",
    "estimate_margin",
    "label_chunk",
    "read_cell",
    "cell_runs",
    "chunk_runs",
    "index_runs",
    "PartitionLayoutError",
    "read_halo",
    "halo_mask",
]

logger = logging.getLogger(__name__)

PARTITION_ATTR = "cloudsieve_partition"
PARTITION_VERSION = 2  # 2: sparse run tables (chunk_runs/cell_runs); 1 had a dense counts table
#: halo margin, in k-NN radii of the full-density cloud
HALO_RADII = 3.0
#: nearest centres tested per point when listing halo sources
HALO_NEIGHBOURS = 5
#: inner chunk of the sharded ``partition/xyz`` rows (points)
INNER_CHUNK = 16384
#: points labelled at once inside a chunk task (bounds the k-d tree query arrays)
_LABEL_BLOCK = 131072
#: zarr chunk of the run tables (runs)
_RUN_CHUNK = 65536
#: runs held in memory while the run tables are built
_RUN_FLUSH = 1 << 21


def sample_size(n: int, n_cells: int) -> int:
    """Points in the uniform sample the centres are fitted on."""
    return int(min(n, max(50_000, 256 * n_cells), 1_000_000))


def plan_sample(n: int, n_cells: int, seed: int) -> np.ndarray:
    """Sorted indices of the uniform sample, drawn from (seed, "partition").

    Returns
    -------
    ndarray of shape (S,), int64, sorted
    """
    s = sample_size(n, n_cells)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x9A27]))
    if s >= n:
        return np.arange(n, dtype=np.int64)
    return np.sort(rng.choice(n, size=s, replace=False)).astype(np.int64)


def sample_chunk(store_path: str, start: int, stop: int, indices: np.ndarray) -> np.ndarray:
    """Coordinates of the sample points in ``[start, stop)`` (a task).

    Returns
    -------
    ndarray of shape (len(indices), 3), float64
    """
    from ..store import PointStore

    if len(indices) == 0:
        return np.empty((0, 3))
    st = PointStore.open(store_path, "r")
    xyz = st.read("xyz", start, stop)
    return xyz[np.asarray(indices) - start]


def fit_centers(sample: np.ndarray, n_cells: int, seed: int, origin: np.ndarray) -> np.ndarray:
    """P centres by K-means on the sample (relative to *origin*), absolute coordinates.

    Returns
    -------
    ndarray of shape (n_cells, 3), float64, sorted lexicographically (x, y, z)
    so that cell ids do not depend on the K-means initialisation order.
    """
    from ..core.cluster import KMeans

    rel = sample - origin
    if n_cells <= 1:
        centers = rel.mean(axis=0, keepdims=True) if len(rel) else np.zeros((1, 3))
    else:
        km = KMeans(n_clusters=n_cells, seed=int(seed)).fit(rel)
        centers = np.asarray(km.cluster_centers_, dtype=np.float64)
    centers = centers + origin
    order = np.lexsort((centers[:, 2], centers[:, 1], centers[:, 0]))
    return np.ascontiguousarray(centers[order])


def estimate_margin(sample: np.ndarray, n_total: int, k: int, seed: int) -> tuple[float, float, float]:
    """k-NN radius of the full cloud, estimated on the sample; and the halo margin.

    The median distance to the k-th neighbour is measured at sample sizes S
    and S/8; their ratio gives the intrinsic dimension d (clipped to [1, 3]),
    and ``r_full = r_S * (S / N) ** (1 / d)``.

    Returns
    -------
    (r_k, dimension, margin) : tuple of float
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
    r1 = float(np.median(cKDTree(rel).query(q, k=k + 1)[0][:, k]))
    r2 = float(np.median(cKDTree(sub).query(q, k=k + 1)[0][:, k]))
    if r1 > 0 and r2 > r1:
        d = float(np.clip(math.log(8.0) / math.log(r2 / r1), 1.0, 3.0))
    else:
        d = 3.0
    r = r1 * (s / max(n_total, 1)) ** (1.0 / d)
    return r, d, HALO_RADII * r


def _nearest(tree: cKDTree, xyz: np.ndarray, kq: int) -> tuple[np.ndarray, np.ndarray]:
    d, nn = tree.query(xyz, k=kq)
    if kq == 1:
        return d[:, None], nn[:, None]
    return d, nn


def _lowest_tied(d: np.ndarray, nn: np.ndarray) -> np.ndarray:
    """Nearest centre of each row of a k-NN answer, exact ties to the lower index."""
    labels = nn[:, 0].astype(np.int64)
    # d is sorted, so tied columns come first
    for col in range(1, d.shape[1]):
        same = d[:, col] == d[:, 0]
        if not same.any():
            break
        tie = same & (nn[:, col] < labels)
        labels[tie] = nn[tie, col]
    return labels


def label_block(centers: np.ndarray, xyz: np.ndarray, margin: float, tree: cKDTree | None = None, halo: bool = True):
    """Cell of each point (nearest centre, ties to the lower index) and halo pairs.

    With ``halo=False`` (no density context: the cell tasks never read a
    halo) only the 2 nearest centres are queried, the rows with a tie again
    with ``HALO_NEIGHBOURS + 1``, and no pairs are returned (measured, CPU
    time for 1 M points of benchmarks/make_scan.py into 10 cells: 0.15 s
    instead of 0.22 s).

    The halo test uses the distances the k-d tree already returned:
    ``s_ij(z) = (|z - c_i|^2 - |z - c_j|^2) / (2 |c_i - c_j|)``, the same
    bisector distance as :func:`halo_distance` up to rounding; pairs are only
    candidates (the cell task applies the exact test), so a relative slack
    of 1e-6 of the margin keeps them a superset.

    Returns
    -------
    labels : ndarray of shape (n,), int64
    pairs : ndarray of shape (q, 2), int64
        Distinct (halo cell i, source cell j) pairs: some point of cell j lies
        within *margin* of the bisector of c_i and c_j.
    """
    p = len(centers)
    if tree is None:
        tree = cKDTree(centers)
    kq = min(p, HALO_NEIGHBOURS + 1)
    if not halo:
        d, nn = _nearest(tree, xyz, min(p, 2))
        labels = nn[:, 0].astype(np.int64)
        if p > 1:
            tied = np.flatnonzero(d[:, 1] == d[:, 0])
            if len(tied):
                labels[tied] = _lowest_tied(*_nearest(tree, xyz[tied], kq))
        return labels, np.empty((0, 2), dtype=np.int64)
    d, nn = _nearest(tree, xyz, kq)
    labels = _lowest_tied(d, nn)
    if kq == 1:
        return labels, np.empty((0, 2), dtype=np.int64)
    d2 = d * d
    other = nn[:, 1:].astype(np.int64)
    # cheap bound first: s_ij <= margin needs d_i - d_j <= 2 margin (|c_i - c_j| >= d_i - d_j)
    cand = (d[:, 1:] - d[:, :1]) <= 2.0 * margin * (1 + 1e-6) + 1e-12
    rows, cols = np.nonzero(cand)
    if len(rows):
        i = other[rows, cols]
        j = labels[rows]
        diff = centers[i] - centers[j]
        cd = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        with np.errstate(invalid="ignore", divide="ignore"):  # i == j gives 0/0, masked out below
            s = (d2[rows, cols + 1] - d2[rows, 0]) / (2.0 * cd)
        hit = (i != j) & (s <= margin * (1 + 1e-6) + 1e-12)
        keys = np.unique(i[hit] * p + j[hit])
        pairs = np.stack([keys // p, keys % p], axis=1)
    else:
        pairs = np.empty((0, 2), dtype=np.int64)
    return labels, pairs


def halo_distance(z: np.ndarray, ci: np.ndarray, cj: np.ndarray) -> np.ndarray:
    """Signed distance of points z of cell j to the bisector plane of c_i and c_j.

    Positive on c_j's side. ``ci``/``cj`` broadcast against ``z`` (n, 3).

    Returns
    -------
    ndarray of shape (n,), float64
    """
    diff = cj - ci
    mid = (ci + cj) * 0.5
    norm = np.sqrt((diff * diff).sum(axis=-1))
    return ((z - mid) * diff).sum(axis=-1) / norm


def label_chunk(
    store_path: str, chunk: int, start: int, stop: int, margin: float, halo: bool = True
) -> tuple[np.ndarray, int]:
    """Label + bucket task for input chunk *chunk* (points ``[start, stop)``).

    Reads the centres from ``partition/centers`` (not passed through the
    scheduler: P x 3 floats per task would be O(n_chunks x P) in all). Writes
    ``partition/cell[start:stop]``, ``partition/xyz[chunk, :stop - start]`` (the
    chunk sorted by cell, stable) and the chunk's nonzero runs (cell, count),
    cells increasing, into ``partition/label_runs[chunk, :nnz]`` (a scratch
    array read back by :func:`index_runs`).

    Returns
    -------
    pairs : ndarray of shape (q, 2), int64
        Distinct (halo cell, source cell) pairs seen in this chunk (small).
    nnz : int
        Number of cells with points in this chunk.
    """
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    g = st.group
    centers = np.asarray(g["partition/centers"][:])
    xyz = st.read("xyz", start, stop)
    n = len(xyz)
    tree = cKDTree(centers)
    labels = np.empty(n, dtype=np.int64)
    pairs = []
    for a in range(0, n, _LABEL_BLOCK):
        lab, pr = label_block(centers, xyz[a : a + _LABEL_BLOCK], margin, tree, halo)
        labels[a : a + _LABEL_BLOCK] = lab
        pairs.append(pr)
    order = np.argsort(labels, kind="stable")
    sl = labels[order]
    heads = np.flatnonzero(np.r_[True, sl[1:] != sl[:-1]]) if n else np.empty(0, np.int64)
    cells = sl[heads]
    counts = np.diff(np.r_[heads, n])
    g["partition/cell"][start:stop] = labels.astype(np.int32)
    g["partition/xyz"][chunk, :n] = xyz[order]
    if len(cells):
        g["partition/label_runs"][chunk, : len(cells)] = np.stack([cells, counts], axis=1).astype(np.int64)
    if pairs:
        u = np.unique(np.concatenate(pairs, axis=0), axis=0)
    else:
        u = np.empty((0, 2), dtype=np.int64)
    return u, int(len(cells))


def _chunks_1d(n: int) -> int:
    return max(1, min(int(n), _RUN_CHUNK))


def index_runs(group, nnz: np.ndarray, n_cells: int, chunk_size: int, flush: int | None = None) -> None:
    """Build the run tables (both CSR views) from the label pass's scratch rows.

    Streams ``partition/label_runs`` chunk by chunk and writes
    ``chunk_ptr``/``chunk_runs`` (by chunk, with each run's position inside
    its cell) and ``cell_ptr``/``cell_runs`` (by cell, chunks increasing) and
    ``cell_count``; then deletes the scratch array. Memory: arrays of size P
    and n_chunks, plus a buffer of *flush* runs (the by-cell view is written
    in blocks of cells holding about *flush* runs, one pass over the by-chunk
    view per block: one pass unless the input is spatially incoherent).

    Parameters
    ----------
    group : zarr.Group
    nnz : ndarray of shape (n_chunks,)
        Runs of each chunk (as returned by :func:`label_chunk`).
    n_cells : int
    chunk_size : int
        Points per input chunk (chunk c starts at point c * chunk_size).
    """
    from ..store import compressors

    flush = int(flush or _RUN_FLUSH)
    nnz = np.asarray(nnz, dtype=np.int64)
    n_chunks, p = len(nnz), int(n_cells)
    chunk_ptr = np.zeros(n_chunks + 1, dtype=np.int64)
    np.cumsum(nnz, out=chunk_ptr[1:])
    total = int(chunk_ptr[-1])
    rc = _chunks_1d(total)
    comp = compressors()
    for name in ("chunk_ptr", "chunk_runs", "cell_ptr", "cell_runs", "cell_count"):
        if f"partition/{name}" in group:
            del group[f"partition/{name}"]
    by_chunk = group.create_array("partition/chunk_runs", shape=(total, 3), dtype="int64", chunks=(rc, 3), compressors=comp)
    tmp = group["partition/label_runs"]
    acc = np.zeros(p, dtype=np.int64)  # points of each cell in the chunks seen so far
    n_runs = np.zeros(p, dtype=np.int64)
    buf: list[np.ndarray] = []
    held, pos = 0, 0
    for c in range(n_chunks):
        k = int(nnz[c])
        if k == 0:
            continue
        r = np.asarray(tmp[c, :k])
        cells, cnt = r[:, 0], r[:, 1]  # cells distinct and increasing within a chunk
        buf.append(np.stack([cells, cnt, acc[cells]], axis=1))
        acc[cells] += cnt
        n_runs[cells] += 1
        held += k
        if held >= max(flush, rc):
            rows = np.concatenate(buf)
            m = (len(rows) // rc) * rc  # aligned writes: no zarr chunk written twice
            by_chunk[pos : pos + m] = rows[:m]
            pos += m
            buf, held = [rows[m:]], len(rows) - m
    if held:
        rows = np.concatenate(buf)
        by_chunk[pos : pos + len(rows)] = rows
    cell_ptr = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(n_runs, out=cell_ptr[1:])
    by_cell = group.create_array("partition/cell_runs", shape=(total, 3), dtype="int64", chunks=(rc, 3), compressors=comp)
    j0 = 0
    while j0 < p and total:
        # a block of cells whose runs fit the buffer (at least one cell)
        j1 = max(j0 + 1, int(np.searchsorted(cell_ptr, cell_ptr[j0] + flush, side="right")) - 1)
        j1 = min(j1, p)
        base = int(cell_ptr[j0])
        out = np.empty((int(cell_ptr[j1]) - base, 3), dtype=np.int64)
        fill = cell_ptr[j0:j1] - base
        done_points = 0  # points of the by-chunk runs before the slice
        for a in range(0, total, max(flush, rc)):
            b = min(total, a + max(flush, rc))
            rows = np.asarray(by_chunk[a:b])
            cum = done_points + np.cumsum(rows[:, 1]) - rows[:, 1]  # points before each run, input order
            done_points += int(rows[:, 1].sum())
            sel = np.flatnonzero((rows[:, 0] >= j0) & (rows[:, 0] < j1))
            if not len(sel):
                continue
            chunk_of = np.searchsorted(chunk_ptr, a + sel, side="right") - 1
            local = cum[sel] - chunk_of * int(chunk_size)  # start of the run in its row of partition/xyz
            o = np.argsort(rows[sel, 0], kind="stable")  # by cell, chunks stay increasing
            cs = rows[sel, 0][o] - j0
            heads = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
            sizes = np.diff(np.r_[heads, len(cs)])
            rank = np.arange(len(cs)) - np.repeat(heads, sizes)
            at = fill[cs] + rank
            out[at, 0] = chunk_of[o]
            out[at, 1] = local[o]
            out[at, 2] = rows[sel, 1][o]
            fill[cs[heads]] += sizes
        by_cell[base : base + len(out)] = out
        j0 = j1
    for name, data in (("chunk_ptr", chunk_ptr), ("cell_ptr", cell_ptr), ("cell_count", acc)):
        group.create_array(f"partition/{name}", data=data, chunks=(_chunks_1d(len(data)),), compressors=comp)
    del group["partition/label_runs"]


def cell_runs(group, cell: int) -> np.ndarray:
    """The runs of *cell* read from the store: rows (chunk, start, stop, first), shape (r, 4).

    ``partition/xyz[chunk, start:stop]`` are the points; ``first`` is the
    position of the run's first point among the cell's points (the runs are
    in increasing chunk, i.e. input, order).
    """
    a, b = (int(v) for v in group["partition/cell_ptr"][cell : cell + 2])
    r = np.asarray(group["partition/cell_runs"][a:b]) if b > a else np.empty((0, 3), np.int64)
    first = np.cumsum(r[:, 2]) - r[:, 2]
    return np.stack([r[:, 0], r[:, 1], r[:, 1] + r[:, 2], first], axis=1).astype(np.int64)


def chunk_runs(group, chunk: int) -> np.ndarray:
    """The runs of input chunk *chunk*: rows (cell, count, first), cells increasing, shape (r, 3).

    ``first`` is the position of the run's first point among its cell's points.
    """
    a, b = (int(v) for v in group["partition/chunk_ptr"][chunk : chunk + 2])
    if b <= a:
        return np.empty((0, 3), np.int64)
    return np.asarray(group["partition/chunk_runs"][a:b]).astype(np.int64)


@dataclass
class Partition:
    """The partition of a store, as read back from ``partition/`` (arrays of size P only).

    Attributes
    ----------
    centers : ndarray of shape (P, 3)
    cell_counts : ndarray of shape (P,), int64
        Points per cell.
    halo_ptr : ndarray of shape (P + 1,), int64
    halo_src : ndarray of shape (h,), int64
        Cells that may hold halo points of cell i: ``halo_src[halo_ptr[i]:halo_ptr[i+1]]``.
    margin : float
    chunk_size : int
        Points per input chunk.
    n_chunks, n_runs : int
        Input chunks; nonzero (chunk, cell) runs.
    group : zarr.Group
        The store's group: the run tables are read from it on demand.
    """

    centers: np.ndarray
    cell_counts: np.ndarray
    halo_ptr: np.ndarray
    halo_src: np.ndarray
    margin: float
    chunk_size: int
    n_chunks: int
    n_runs: int
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
            The store holds no complete partition, or one written in another
            layout (an older cloudsieve): partition the store again.
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
            group=g,
        )


def read_runs(group, runs: np.ndarray) -> np.ndarray:
    """Concatenate the ``partition/xyz`` runs ``(chunk, start, stop, ...)``.

    Returns
    -------
    ndarray of shape (sum(stop - start), 3), float64
    """
    arr = group["partition/xyz"]
    parts = [np.asarray(arr[int(r[0]), int(r[1]) : int(r[2])]) for r in runs if r[2] > r[1]]
    if not parts:
        return np.empty((0, 3))
    return np.concatenate(parts, axis=0)


def read_cell(group, runs: np.ndarray) -> np.ndarray:
    """Core points of a cell (increasing input index), from its runs.

    Returns
    -------
    ndarray of shape (n, 3), float64
    """
    return read_runs(group, runs)


def halo_mask(z: np.ndarray, centers: np.ndarray, cell: int, source: int, margin: float) -> np.ndarray:
    """Which points z of cell *source* belong to the halo of *cell*.

    Returns
    -------
    ndarray of shape (n,), bool
    """
    return halo_distance(z, centers[cell], centers[source]) <= margin


def read_halo(group, part_runs: dict[int, np.ndarray], centers: np.ndarray, cell: int, margin: float,
              return_index: bool = False):
    """Halo of *cell*: points of its halo source cells within *margin* of its region.

    Parameters
    ----------
    part_runs : dict int -> ndarray of shape (r, 3) or (r, 4)
        Runs ``(chunk, start, stop[, first])`` of each halo source cell (see
        :meth:`Partition.runs`); ``first`` is the position of the run's first
        point among its cell's points (needed for *return_index*).
    return_index : bool
        Also return, for every halo point, its cell and its position among
        that cell's points (to look up per-cell results such as scores).

    Returns
    -------
    points : ndarray of shape (h, 3), float64
        Source cells in increasing id, each in increasing input index.
    cells, positions : ndarray of shape (h,), int64
        Only with *return_index*.
    """
    arr = group["partition/xyz"]
    out, cells, pos = [], [], []
    for src in sorted(part_runs):
        for run in part_runs[src]:
            c, a, b = (int(v) for v in run[:3])
            if b <= a:
                continue
            z = np.asarray(arr[c, a:b])
            m = halo_mask(z, centers, cell, src, margin)
            if m.any():
                out.append(z[m])
                if return_index:
                    sel = np.flatnonzero(m)
                    cells.append(np.full(len(sel), src, dtype=np.int64))
                    pos.append(int(run[3]) + sel)
    pts = np.concatenate(out, axis=0) if out else np.empty((0, 3))
    if not return_index:
        return pts
    if not out:
        return pts, np.empty(0, np.int64), np.empty(0, np.int64)
    return pts, np.concatenate(cells), np.concatenate(pos).astype(np.int64)


def n_cells_for(n: int, cell_size: int) -> int:
    """P = ceil(N / cell_size), at least 1."""
    return max(1, -(-int(n) // int(cell_size)))


def row_layout(chunk_size: int) -> tuple[int, int]:
    """(R, inner): a ``partition/xyz`` row holds R >= chunk_size points in inner chunks."""
    inner = min(INNER_CHUNK, chunk_size)
    return -(-chunk_size // inner) * inner, inner


def build_partition(
    store, *, cell_size: int, cluster_size: int, seed: int, run, k0: float = 1.0, k_min: int = 4, halo: bool = True
) -> Partition:
    """Partition *store* into cells (stage 2) and record it in the store.

    Parameters
    ----------
    store : PointStore
        Opened writable ("r+").
    cell_size : int
        Target points per cell; P = ceil(N / cell_size).
    cluster_size : int
        Points per small cluster of the refine stage (sets the halo's k).
    seed : int
    run : callable
        ``run(func, argument_tuples, stage) -> list of results in order``: the
        engine's task runner (any dask scheduler).
    halo : bool
        List the halo sources of every cell (needed by cell tasks that use a
        density context); False leaves them empty and labels faster. Recorded
        as ``"halo"`` in the partition's attributes.

    Returns
    -------
    Partition
    """
    n = store.count
    chunk = store.chunk_size
    p = n_cells_for(n, cell_size)
    starts = list(range(0, n, chunk))
    n_chunks = len(starts)
    path = store.path

    idx = plan_sample(n, p, seed)
    bounds = np.searchsorted(idx, [min(s + chunk, n) for s in starts])
    lo = np.concatenate([[0], bounds[:-1]])
    args = [(path, s, min(s + chunk, n), idx[a:b]) for s, a, b in zip(starts, lo, bounds)]
    parts = run(sample_chunk, args, "partition: sample")
    sample = np.concatenate(parts, axis=0) if parts else np.empty((0, 3))
    origin = np.asarray(store.bounds[0], dtype=np.float64)
    centers = fit_centers(sample, p, seed, origin)
    k = max(int(k_min), int(round(k0 * math.sqrt(cluster_size))))
    r_k, dim, margin = estimate_margin(sample - origin, n, k, seed)
    logger.info("partition: %d points -> %d cells, sample %d, r_%d=%.4g (d=%.2f), margin %.4g", n, p, len(sample), k, r_k, dim, margin)

    g = store.group
    from ..store import compressors

    for name in ("cell", "counts", "xyz", "centers", "halo_ptr", "halo_src", "label_runs",
                 "chunk_ptr", "chunk_runs", "cell_ptr", "cell_runs", "cell_count"):
        if f"partition/{name}" in g:
            del g[f"partition/{name}"]
    g.create_array("partition/centers", data=centers, chunks=centers.shape, compressors=compressors())
    g.create_array("partition/cell", shape=(n,), dtype="int32", chunks=(chunk,), compressors=compressors(), fill_value=-1)
    r_len, inner = row_layout(chunk)
    g.create_array(
        "partition/xyz",
        shape=(n_chunks, r_len, 3),
        dtype="float64",
        chunks=(1, inner, 3),
        shards=(1, r_len, 3),
        compressors=compressors(),
    )
    # scratch: row c holds chunk c's nonzero runs; only the zarr chunks a task
    # writes are stored (about nnz entries), the logical shape is never filled
    width = max(1, min(chunk, p))
    g.create_array(
        "partition/label_runs", shape=(n_chunks, width, 2), dtype="int64",
        chunks=(1, min(width, 4096), 2), compressors=compressors(),
    )
    args = [(path, c, s, min(s + chunk, n), margin, bool(halo)) for c, s in enumerate(starts)]
    results = run(label_chunk, args, "partition: label")
    pair_lists = [r[0] for r in results]
    nnz = np.array([r[1] for r in results], dtype=np.int64)
    pairs = np.unique(np.concatenate(pair_lists, axis=0), axis=0) if pair_lists else np.empty((0, 2), np.int64)
    halo_ptr = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=p), out=halo_ptr[1:])
    halo_src = pairs[:, 1].astype(np.int64)  # rows sorted by (i, j)
    index_runs(g, nnz, p, chunk)
    g.create_array("partition/halo_ptr", data=halo_ptr, chunks=halo_ptr.shape, compressors=compressors())
    g.create_array("partition/halo_src", data=halo_src, chunks=(max(1, len(halo_src)),), compressors=compressors())
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
        "complete": True,
    }
    g.attrs.update({PARTITION_ATTR: meta})
    return Partition.load(store)
