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
    on *cells*, with its functions on arrays: each cell's share, the counts, then each cell's elimination
    colour by colour, in the order of the store's run."""
    from ..core.colours import cell_colours
    from .eliminate import apply_order, cell_counts, cell_keep, cell_share
    from .halo import band_halo

    p, r_max, margin, c, members = cells.n_cells, cells.r_max, cells.margin, cells.centers, cells.members
    owner = np.repeat(np.arange(p), np.diff(cells.halo_ptr))  # the cells that read each cell's band
    readers = [owner[cells.halo_src == j] for j in range(p)]

    def share(j: int) -> tuple:  # share_task's work, the ladder only for more than one cell
        deps = {int(i): c[i] for i in sorted(set(readers[j].tolist()))}
        return cell_share(take_rows(xyz, members[j]), r_max, c, j, deps, margin, ladder=p > 1)

    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:  # the cells at once, as the workers run the share tasks
        shares = list(pool.map(share, range(p)))
    sizes, distinct = np.array([s[0] for s in shares]).reshape(p, -1), np.array([s[1] for s in shares])
    bands = [members[j][s[2]] for j, s in enumerate(shares)]  # the rows of each cell's band
    q, staged = cell_counts(sizes, distinct, target, r_max)
    colours = cell_colours(cells.halo_ptr, cells.halo_src)
    keep = np.zeros(len(xyz), dtype=bool)
    for j in apply_order(colours, [len(m) for m in members], range(p)):  # apply_task's work
        core = take_rows(xyz, members[j])
        halo = None
        if 0 < q[j] < len(core):
            sources = sorted(int(s) for s in cells.halo_sources(j))
            points, src_of, rows = band_halo(((s, take_rows(xyz, bands[s]), bands[s]) for s in sources
                                              if len(bands[s])), c, j, margin)
            fixed = np.isin(src_of, [s for s in sources if colours[s] < colours[j]])
            halo = (points, fixed, fixed & keep[rows])
        keep[members[j]] = cell_keep(core, int(q[j]), r_max, halo, os.cpu_count() or 1, staged, keep_duplicates)
    return keep, int(distinct.sum())
