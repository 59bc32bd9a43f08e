"""The partition and the cells of a small input in memory: the eliminate rule's stages on arrays.

:mod:`.small` reads a small cloud into memory; this module runs the
out-of-core run's stages 2 and 3 on it with the same functions, in the same
order, so the kept set is the work store's (tests/test_engine_small.py):

1. the partition (:func:`partition`): the uniform sample
   (:func:`~.sample.plan_sample`), its K-means centres, the margin (at least
   :data:`~.partition.ELIMINATE_RADII` r_max) and r_max
   (:func:`~.partition.fit_sample`), and every point's cell and the
   cells' halo sources (:func:`~.label.label_points`, as a label task labels
   its chunk);
2. the shares (:func:`~cloudsieve.core.packing.packing_ladder`) and bands
   (:func:`~.halo.band_mask`) of the cells, their counts
   (:func:`~cloudsieve.core.packing.kept_counts`);
3. the elimination of each cell colour by colour
   (:func:`~cloudsieve.core.colours.cell_colours`), its halo the points of
   its sources' bands within the margin (:func:`~.halo.halo_mask`), in the
   order :func:`~.halo.read_band_halo` reads them, the lower colours' final
   decisions fixed (:func:`~cloudsieve.core.eliminate_cells.eliminate_cell`).

A cell's points are in input order, as the store's cell runs hold them.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..chunk import take_rows
from ..core.kernels.scatter import group_rows

__all__ = ["Cells", "partition", "eliminate_cells"]


class Cells:
    """A small cloud's partition: the cell of each point, the centres, the halo sources, r_max, the margin."""

    def __init__(self, labels: np.ndarray, centers: np.ndarray, halo_ptr: np.ndarray, halo_src: np.ndarray,
                 r_max: float, margin: float) -> None:
        self.labels, self.centers, self.r_max, self.margin = labels, centers, r_max, margin
        self.halo_ptr, self.halo_src = halo_ptr, halo_src
        # each cell's points in input order, counted on the cores (numpy's stable sort of 16-bit labels: 0.11-0.38 s
        # for 10 M on one)
        order, bounds = group_rows(labels, len(centers), os.cpu_count() or 1)
        self.members = [order[bounds[j] : bounds[j + 1]] for j in range(len(centers))]

    @property
    def n_cells(self) -> int:
        return len(self.centers)

    def halo_sources(self, cell: int) -> np.ndarray:
        return self.halo_src[self.halo_ptr[cell] : self.halo_ptr[cell + 1]]


def partition(xyz: np.ndarray, origin: np.ndarray, opts: dict, target: int) -> Cells:
    """:func:`~.partition.build_partition` of the eliminate rule (a halo, r_max for *target*) on *xyz*."""
    from ..core import neighbour_count
    from .partition import fit_sample
    from .sample import n_cells_for, plan_sample

    n = len(xyz)
    p = n_cells_for(n, opts["cell_size"])
    seed = opts["seed"]
    sample = xyz[plan_sample(n, p, seed)]
    k = int(neighbour_count(opts["cluster_size"], opts["k0"], opts["k_min"]))
    centers, (_, _, margin), r_max = fit_sample(sample, n, p, seed, origin, k, int(target))
    labels, pairs = np.zeros(n, dtype=np.int64), np.empty((0, 2), dtype=np.int64)
    if p > 1:  # as the label tasks (each point's label is its own: the store's chunks do not matter)
        from .label import label_points

        labels, pairs = label_points(centers, xyz, margin, threads=os.cpu_count() or 1)
    halo_ptr = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=p), out=halo_ptr[1:])
    return Cells(labels, centers, halo_ptr, pairs[:, 1].astype(np.int64), r_max, margin)


def eliminate_cells(xyz: np.ndarray, cells: Cells, target: int, keep_duplicates: bool) -> tuple[np.ndarray, int]:
    """The keep mask (input order) and the distinct points of the stage :func:`~.eliminate.run_eliminate`
    on *cells*: the shares, the counts, then each cell's elimination colour by colour."""
    from ..core.colours import cell_colours
    from ..core.duplicates import copy_rows, first_copies
    from ..core.eliminate import CELL_POINTS
    from ..core.eliminate_cells import eliminate_cell
    from ..core.packing import LADDER, kept_counts, ladder_shares, packing_ladder
    from ..core.staged import small_share
    from .halo import band_mask, halo_mask

    p, r_max, margin, c = cells.n_cells, cells.r_max, cells.margin, cells.centers
    threads = os.cpu_count() or 1
    owner = np.repeat(np.arange(p), np.diff(cells.halo_ptr))  # the cells that read each cell's band
    readers = [owner[cells.halo_src == j] for j in range(p)]
    shares, distinct = np.zeros((p, len(LADDER))), np.zeros(p, dtype=np.int64)

    def share(j: int) -> np.ndarray:  # share_task: the cell's packing sizes and distinct points; its band
        core = take_rows(xyz, cells.members[j])
        if len(core) and math.isfinite(r_max) and p > 1:  # one cell's count is the target: no share to weigh
            shares[j], distinct[j] = packing_ladder(core, r_max)
        elif len(core):
            distinct[j] = len(core) - copy_rows(core).sum()
        deps = {int(i): c[i] for i in sorted(set(readers[j].tolist()))}
        return np.flatnonzero(band_mask(core, {**deps, j: c[j]}, j, deps, margin))

    with ThreadPoolExecutor(threads) as pool:  # the cells at once, as the workers run the share tasks
        bands = list(pool.map(share, range(p)))
    expected = ladder_shares(shares, int(target)) if math.isfinite(r_max) else distinct
    q = kept_counts(expected, distinct, int(target))
    staged = small_share(int(target), int(distinct.sum()))  # as run_eliminate: one decision for every cell
    colours = cell_colours(cells.halo_ptr, cells.halo_src)
    keep = np.zeros(len(xyz), dtype=bool)
    for j in sorted(range(p), key=lambda j: (colours[j], -len(cells.members[j]), j)):  # apply_task
        own = cells.members[j]
        core = take_rows(xyz, own)
        n = len(core)
        mine = np.full(n, q[j] >= n)
        if 0 < q[j] < n:
            sources = sorted(int(s) for s in cells.halo_sources(j))
            parts = [(s, cells.members[s][bands[s]]) for s in sources if len(bands[s])]
            rows = [b[halo_mask(take_rows(xyz, b), {j: c[j], s: c[s]}, j, s, margin)] for s, b in parts]
            src_of = np.concatenate([np.full(len(r), s) for (s, _), r in zip(parts, rows)] + [np.zeros(0, int)])
            rows = np.concatenate(rows + [np.zeros(0, dtype=np.int64)])
            fixed = np.isin(src_of, [s for s in sources if colours[s] < colours[j]])
            halo_keep = fixed & keep[rows]
            mine = eliminate_cell(core, int(q[j]), r_max, halo=take_rows(xyz, rows), decided=fixed, halo_keep=halo_keep,
                                  threads=threads, cell_points=CELL_POINTS, staged=staged)
        if keep_duplicates and n:  # every copy of a kept point too
            mine = mine[first_copies(core)]
        keep[own] = mine
    return keep, int(distinct.sum())
