"""The eliminate rule's cell scheme on arrays: the functions every run of the rule calls.

The store's run (:mod:`.eliminate`, one task a cell), a small input in
memory (:mod:`.small`) and the in-memory API (``simplify_points`` with the
rule ``eliminate``: :func:`eliminate_points`) run the same steps, so a
cloud's kept set does not depend on where it runs (tests/test_engine_small.py):

1. the partition (:func:`partition` in memory, the store's
   :func:`~.partition.build_partition`): the uniform sample
   (:func:`~.sample.plan_sample`), its K-means centres, the margin (at least
   :data:`~.partition.ELIMINATE_RADII` r_max) and r_max
   (:func:`~.partition.fit_sample`), and every point's cell and the
   cells' halo sources (:func:`~.label.label_points`, as a label task labels
   its chunk);
2. each cell's share (:func:`cell_share`: its packing sizes, distinct points
   and band), then every cell's count (:func:`cell_counts`);
3. the elimination of each cell (:func:`cell_keep`) in the order of
   :func:`~cloudsieve.core.colours.apply_order` (colour by colour,
   :func:`~cloudsieve.core.colours.cell_colours`), its halo the points of
   its sources' bands within the margin (:func:`~.halo.band_halo`), the
   lower colours' final decisions fixed.

In memory (:func:`eliminate_cells`) a cell's points are in input order, as
the store's cell runs hold them.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..chunk import take_rows
from ..core.kernels.scatter import group_rows
from .halo import band_mask

__all__ = ["Cells", "partition", "eliminate_cells", "eliminate_points", "cell_share", "cell_counts", "cell_keep"]


class Cells:
    """A partition in memory: the cell of each point, the centres, the halo sources, r_max, the margin."""

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
    from .partition import fit_sample, halo_lists
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
    return Cells(labels, centers, *halo_lists(pairs, p), r_max, margin)


def eliminate_cells(xyz: np.ndarray, cells: Cells, target: int, keep_duplicates: bool) -> tuple[np.ndarray, int]:
    """The keep mask (input order) and the distinct points of the stage :func:`~.eliminate.run_eliminate`
    on *cells*, with its functions on arrays: each cell's share, the counts, then each cell's elimination
    colour by colour, in the order of the store's run."""
    from ..core.colours import apply_order, cell_colours, readers
    from .halo import band_halo

    p, r_max, margin, c, members = cells.n_cells, cells.r_max, cells.margin, cells.centers, cells.members
    deps = readers(cells.halo_ptr, cells.halo_src)  # the cells that read each cell's band

    def share(j: int) -> tuple:  # share_task's work, the ladder only for more than one cell
        return cell_share(take_rows(xyz, members[j]), r_max, c, j, {int(i): c[i] for i in deps[j]}, margin,
                          ladder=p > 1)

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


def eliminate_points(xyz: np.ndarray, target: int, *, seed: int, cluster_size: int, k0: float, k_min: int,
                     keep_duplicates: bool) -> np.ndarray:
    """The keep mask (n,) of the cloud *xyz* (n, 3) float64 reduced to *target* points as a run of the engine
    keeps it with these options and the default ``cell_size``: :func:`partition`, then :func:`eliminate_cells`
    (the in-memory API's rule ``eliminate``)."""
    from ..chunk import xyz_bounds
    from ..params import COMMANDS

    opts = {"cell_size": COMMANDS["simplify"]["cell_size"].default, "seed": seed, "cluster_size": cluster_size,
            "k0": k0, "k_min": k_min}
    cells = partition(xyz, np.asarray(xyz_bounds(xyz)[0], dtype=np.float64), opts, int(target))
    return eliminate_cells(xyz, cells, int(target), keep_duplicates)[0]


# ---------------------------------------------------------------- a cell's work (the store's tasks call them too)


def cell_share(core: np.ndarray, r_max: float, centers, cell: int, dependents: dict, margin: float,
               threads: int | None = None, ladder: bool = True) -> tuple[np.ndarray, int, np.ndarray]:
    """The packing sizes (L,) of the points *core* (n, 3) of *cell* along
    :data:`~cloudsieve.core.packing.LADDER` x *r_max* (zeros when r_max is infinite or not *ladder*: one
    cell's count is the target), its distinct points, and its band: the positions of its points in the halo of
    a cell of *dependents* (int -> centre; *centers* [cell] its own centre), on *threads* numba threads."""
    from ..core.duplicates import copy_rows
    from ..core.packing import LADDER, packing_ladder
    from ..core.relocate import numba_threads

    n = len(core)
    if n and math.isfinite(r_max) and ladder:
        with numba_threads(threads):  # the task's share of the cores
            sizes, distinct = packing_ladder(core, r_max)
    else:
        sizes, distinct = np.zeros(len(LADDER)), int(n - copy_rows(core).sum()) if n else 0
    band = np.flatnonzero(band_mask(core, {**dependents, cell: centers[cell]}, cell, dependents, margin))
    return sizes, int(distinct), band


def cell_counts(sizes: np.ndarray, distinct: np.ndarray, target: int, r_max: float) -> tuple[np.ndarray, bool]:
    """Each cell's kept count q (P,), summing to *target*, from the cells' packing sizes (P, L) and distinct
    points (P,) (:func:`~cloudsieve.core.packing.kept_counts`), and whether every cell runs in stages
    (:func:`~cloudsieve.core.staged.small_share`: one decision for the run)."""
    from ..core.packing import kept_counts, ladder_shares
    from ..core.staged import small_share

    expected = ladder_shares(sizes, int(target)) if math.isfinite(r_max) else distinct
    return kept_counts(expected, distinct, int(target)), small_share(int(target), int(distinct.sum()))


def cell_keep(core: np.ndarray, count: int, r_max: float, halo: tuple, threads: int | None, staged,
              keep_duplicates) -> np.ndarray:
    """The keep mask (n,) of a cell's points *core* (n, 3): the elimination to *count* of them
    (:func:`~cloudsieve.core.eliminate_cells.eliminate_cell`) with *halo* = (points (h, 3), which are the
    lower colours' final decisions (h,), which of those are kept (h,)); every copy of a kept point with
    *keep_duplicates*."""
    from ..core.eliminate import CELL_POINTS
    from ..core.eliminate_cells import eliminate_cell

    n = len(core)
    keep = np.full(n, count >= n)
    if 0 < count < n:
        points, fixed, halo_keep = halo
        keep = eliminate_cell(core, int(count), r_max, halo=points, decided=fixed, halo_keep=halo_keep,
                              threads=threads, cell_points=CELL_POINTS, staged=staged)
    if keep_duplicates and n:  # every copy of a kept point too
        from ..core.duplicates import first_copies

        keep = keep[first_copies(core)]
    return keep
