"""One cell of the ``eliminate`` rule: its elimination with its halo, over k-d cells on threads.

:func:`eliminate_cell` is the kernel of a cell of every run of the rule
(:mod:`cloudsieve.engine.cell_scheme`: the store's tasks, a small input in
memory, ``simplify_points``), and :func:`cloudsieve.core.eliminate.eliminate`
is :func:`eliminate_cell` of the whole cloud without a halo. One elimination
over many points is sequential (the heaviest point anywhere goes next) and,
at 1 M points, spends most of its time waiting on memory: its arrays no
longer fit the caches. Above ``cell_points`` points the cell is eliminated
over k-d cells on threads (:func:`eliminate_cells`):

1. **cells**: a k-d split (:func:`split_cells`): the longest side of a
   cell's box is cut at the median value of its points' coordinate, until
   every cell holds at most ``cell_points`` points. Cuts are by value, so the
   cells do not depend on the input order nor on the unit, and exact copies
   share a cell.
2. **counts**, first, on all cells at once: each cell's grid and neighbour
   lists (with every halo point, step 3's) and the sizes of greedy packings
   of its points at radii about r_max (:mod:`.packing`, over the lists);
   each cell's size at the radius where they total the target, made exact
   integers by :func:`kept_counts`.
3. **elimination**, colour by colour (:func:`.colours.cell_colours`: cells
   whose halos meet never share a colour, so the cells of one colour run at
   once): each cell runs the elimination of :func:`eliminate_cell` on its
   prepared grid and lists, its halo the points of other cells within
   2.2 r_max of its box: the lower colours' final decisions fixed (kept) or
   gone (removed), the higher colours' points eliminated along. A cell starts
   once the lower-colour cells of its halo are done.

The result is a function of the points, the count and ``cell_points``: not
of the thread count (cells of one colour read nothing of each other, each
elimination runs on one thread) nor of the input order (up to 50,000
points: above, r_max is solved on a seeded sample of rows). On the shared
scans the kept sets had the point RMS of one elimination over the whole
cloud within 1% (README).

:func:`eliminate_cell` builds a cell's lists without the halo points its
lower colours removed: the same priorities but for ties. Above
``cell_points`` it runs :func:`eliminate_cells` on the cell, the halo's
points with their decisions around the k-d cells.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..chunk import take_rows, xyz_bounds
from ..errors import InvalidParameterError
from .cellgrid import CellGrid, check_points
from .colours import apply_order, cell_colours
from .duplicates import copy_rows
from .elimination import ALPHA, alpha_int, keep_lowest, run_elimination
from .kernels import kdcells as _kk
from .kernels import neighbours as _kn
from .kernels import packing as _kp
from .packing import LADDER, kept_counts, ladder_shares
from .relocate import RELOCATE_STEPS, check_r_max, numba_threads, relocate_on_grid
from .staged import eliminate_staged, runs_staged

__all__ = ["HALO_RADII", "cell_cap", "split_cells", "eliminate_cell", "eliminate_direct", "eliminate_cells"]

#: kept points a cell holds at least (at low ratios the cells grow): its halo stays a thin band
MIN_KEPT = 1_024
#: halo margin in r_max: the elimination and the relocation reach 2 r_max (as the engine's)
HALO_RADII = 2.2
#: at least this share of the points kept, every cell's neighbour lists are built ahead, with the packings (about
#: 7 entries a point at 50% kept); below it, each cell's lists are built when the cell runs, its packings walk the
#: grid (3.6 / share entries a point: at 5% kept, autzen_trim in memory peaked at 449 MiB with its 8 cells' lists
#: built ahead, at 310 MiB with each built when its cell runs)
LISTS_AHEAD = 0.2


def split_cells(points: np.ndarray, cell_points: int, threads: int = 1) -> tuple[np.ndarray, np.ndarray,
                                                                              np.ndarray, np.ndarray]:
    """Split *points* (n, 3) into k-d cells of at most *cell_points* points (the halves of a level on
    *threads* threads: the result does not depend on them).

    Returns
    -------
    idx : ndarray of shape (n,), int64
        The points cell by cell, ascending inside each cell.
    starts : ndarray of shape (C + 1,), int64
        Cell c holds ``idx[starts[c]:starts[c + 1]]``.
    boxes : ndarray of shape (C, 2, 3), float64
        Lower and upper corner of each cell's region (+-inf on the cloud's outer sides); the regions tile
        space, touching on the cuts.
    ordered : ndarray of shape (n, 3), float64
        ``points[idx]``: each cell's points a contiguous block.
    """
    n = len(points)
    # the rows and their points, moved cut after cut between two pairs of buffers: a cut reads a node's range
    # of one pair and writes its halves into the other, a cell's range is copied back into the first pair once
    # at the end (a copy back after every cut would move every point once more a level)
    idx = (np.arange(n, dtype=np.int64), np.empty(n, dtype=np.int64))
    ordered = (np.array(points, dtype=np.float64, order="C"), np.empty((n, 3)))
    vals = np.empty(n)
    lo, hi = xyz_bounds(points) if n else (np.zeros(3), np.zeros(3))

    def split(node):  # node: (path, s, e, box, lower and upper extent, its pair); the halves, or None for a cell
        path, s, e, box, a, b, at = node
        if e - s <= cell_points:
            return None
        ext = b - a
        for axis in np.argsort(-ext, kind="stable"):  # the longest side; if every point ties on it, the next
            if not ext[axis] > 0:
                return None
            v, cut = _kk.median_cut(ordered[at][s:e], idx[at][s:e], int(axis), a[axis], b[axis], vals[s:e],
                                    idx[1 - at][s:e], ordered[1 - at][s:e], np.zeros(4096, dtype=np.int64))
            mid = s + cut
            if s < mid < e:
                break
        else:
            return None
        upper, ub = box.copy(), a.copy()
        upper[0, axis] = ub[axis] = v
        lower, lb = box.copy(), b.copy()
        lower[1, axis] = lb[axis] = v
        return (path + (0,), s, mid, lower, a, lb, 1 - at), (path + (1,), mid, e, upper, ub, b, 1 - at)

    level = [((), 0, n, np.array([[-np.inf] * 3, [np.inf] * 3]), lo, hi, 0)]
    cells = []
    with ThreadPoolExecutor(max(1, int(threads))) as pool:
        while level:  # the nodes of one level own disjoint ranges of both pairs and the scratch
            halves = list(pool.map(split, level))
            cells += [node for node, h in zip(level, halves) if h is None]
            level = [x for h in halves if h is not None for x in h]
    for _, s, e, *_, at in cells:
        if at:
            idx[0][s:e] = idx[1][s:e]
            ordered[0][s:e] = ordered[1][s:e]
    idx, ordered = idx[0], ordered[0]
    cells.sort(key=lambda c: c[0])  # depth first, lower side first: a pure function of the coordinates
    starts = np.array([c[1] for c in cells] + [n], dtype=np.int64)
    return idx, starts, np.array([c[3] for c in cells]).reshape(-1, 2, 3), ordered


def _neighbours(boxes: np.ndarray, margin: float) -> list[np.ndarray]:
    """For each cell, the other cells whose boxes come within *margin* of its box."""
    lo, hi = boxes[:, 0] - margin, boxes[:, 1] + margin
    out = []
    for j in range(len(boxes)):
        near = np.flatnonzero(np.all((boxes[:, 0] <= hi[j]) & (boxes[:, 1] >= lo[j]), axis=1))
        out.append(near[near != j])
    return out


def eliminate_cell(points, count: int, r_max, *, halo=None, decided=None, halo_keep=None,
                   steps: int = RELOCATE_STEPS, threads: int | None = None,
                   cell_points: int | None = None, staged: bool | None = None) -> np.ndarray:
    """Keep mask of one cell of a cloud: the elimination to ``count`` with its halo, then relocation.

    The halo points already ``decided`` (a neighbouring cell's final
    result) weigh as fixed points when kept (``halo_keep``) and as gone
    points when removed; the others are eliminated along (not counted).
    Then ``steps`` steps of :func:`relocate` with every kept halo point
    pulling on the regions, on the same grid (one grid for both: the same
    points).

    Above ``cell_points`` points (None: never; :func:`cell_cap`) the cell
    is cut into k-d cells eliminated as :func:`eliminate_cells` does, the
    halo's points with their decisions around them: the engine's cells run
    at the in-memory kernel's speed (one elimination of 200,000 points
    waits on memory, cells of 16,384 fit the caches). In stages of about
    half when ``staged`` (:mod:`.staged`: memory and time as at 50% kept);
    None: when the count is below 1 in :data:`.staged.STAGED_BELOW` of the
    cell's distinct points (the engine decides for all cells of a run at once,
    from the run's count and distinct points).

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    count : int
        Points of ``points`` kept, in [0, n].
    r_max : float
        The cloud's elimination radius.
    halo : array_like of shape (h, 3), optional
    decided, halo_keep : array_like of shape (h,), bool, optional
        Which halo points are decided, and which of those are kept.
    threads : int, optional
    cell_points : int, optional
    staged : bool, optional

    Returns
    -------
    ndarray of shape (n,), bool
        Exactly ``count`` True.
    """
    pts = check_points(points)
    n = len(pts)
    # count and steps come from the engine (kept_counts: in [0, n]) and from params (relocate_steps), not checked here
    r_max = check_r_max(r_max)
    hal = np.zeros((0, 3)) if halo is None else check_points(halo, "halo")
    dec = np.zeros(len(hal), dtype=bool) if decided is None else np.asarray(decided)
    hk = np.zeros(len(hal), dtype=bool) if halo_keep is None else np.asarray(halo_keep)
    for name, a in (("decided", dec), ("halo_keep", hk)):
        if a.shape != (len(hal),) or a.dtype != bool:
            raise InvalidParameterError(f"{name} must be a bool mask of shape ({len(hal)},), got {a.dtype} {a.shape}")
    if count == n or count == 0:
        return np.full(n, count == n)
    if not math.isfinite(r_max):  # no radius (a cloud of at most AREA_K points, or of one spot): as in the whole-cloud
        # elimination, every distinct point has the same priority, its copies +inf: the last `count` distinct stay
        return keep_lowest(np.where(copy_rows(pts), np.inf, 0.0), int(count))
    kind = np.where(dec, np.where(hk, 2, 0), 1).astype(np.uint8)  # free, fixed (kept), gone (removed)
    if runs_staged(pts, int(count)) if staged is None else staged:  # stages of about half (module .staged)
        return eliminate_staged(eliminate_direct, pts, int(count), r_max, hal, kind, int(steps), threads,
                                cell_points)
    return eliminate_direct(pts, int(count), r_max, hal, kind, int(steps), threads, cell_points)


def eliminate_direct(pts: np.ndarray, count: int, r_max: float, hal: np.ndarray, kind: np.ndarray, steps: int,
                     threads, cell_points) -> np.ndarray:
    """:func:`eliminate_cell` as one elimination (no stages) on valid input: *count* in [0, n], r_max finite,
    the halo *hal* (h, 3) and its kinds *kind* (h,) uint8 (1 free, 2 fixed, 0 gone)."""
    n = len(pts)
    if count == n or count == 0:
        return np.full(n, count == n)
    cap = n if cell_points is None else cell_cap(n, int(count), int(cell_points))
    if n > cap:
        workers = max(1, int(threads or 1))
        return eliminate_cells(pts, int(count), r_max, split_cells(pts, cap, workers), int(steps), workers,
                               (hal, kind))
    with numba_threads(threads):
        grid, lists = _grid_lists(pts, hal, r_max, kind == 0)
        return _finish(n, grid, lists, kind, r_max, int(count), int(steps))


def _one_thread(fn, *args):
    """fn(*args) with numba on one thread (a pool thread starts with numba's default count)."""
    with numba_threads(1):
        return fn(*args)


def _grid_state(own: np.ndarray, halo: np.ndarray, r_max: float, absent=None) -> tuple:
    """The grid of [own, halo] (cells of 2 r_max) and the state its lists are built on: every point alive
    but exact copies and the halo points ``absent`` (the ones a lower colour removed, when known: an absent
    point's terms would only make the elimination's first bounds larger)."""
    grid = CellGrid(np.concatenate([own, halo]), 2.0 * r_max)
    state = np.ones(len(grid.order), dtype=np.uint8)
    if absent is not None:
        rows = np.flatnonzero(grid.order >= len(own))
        state[rows[absent[grid.order[rows] - len(own)]]] = 0
    state[grid.copy] = 0
    return grid, state


def _lists(grid, state: np.ndarray, r_max: float) -> tuple:
    """The neighbour lists within 2 r_max of the alive rows of *grid* (module .kernels.neighbours)."""
    return _kn.build_lists(*grid.args(), grid.order, state, 2.0 * r_max, ALPHA, alpha_int(ALPHA), True)


def _grid_lists(own: np.ndarray, halo: np.ndarray, r_max: float, absent=None) -> tuple:
    """The grid of [own, halo] and its neighbour lists within 2 r_max, without the halo points ``absent``
    (:func:`_grid_state`)."""
    grid, state = _grid_state(own, halo, r_max, absent)
    return grid, _lists(grid, state, r_max)


def _prepare(own: np.ndarray, halo: np.ndarray, r_max: float, absent=None, ahead: bool = True) -> tuple:
    """What the elimination of a cell needs before its halo's decisions are known: the grid of [own, halo]
    and its lists' state (:func:`_grid_state`), the neighbour lists when ``ahead`` (else None: built when
    the cell runs), the cell's packing sizes along ``LADDER`` (module .packing; over the lists when built,
    else over the grid: the same sizes) and its distinct points."""
    grid, state = _grid_state(own, halo, r_max, absent)
    join = ((grid.order < len(own)) & ~grid.copy).astype(np.uint8)
    rad = np.array(LADDER) * r_max
    r2 = rad * rad
    if ahead:
        lists = _lists(grid, state, r_max)
        counts = _kp.packing_from_lists(grid.P, lists[0], lists[1], join, r2)
    else:
        lists = None
        counts = _kp.packing_counts(*grid.args(), join == 0, r2)
    return grid, lists, counts, int(join.sum()), state


def _finish(n: int, grid, lists, kind: np.ndarray, r_max: float, count: int, steps: int) -> np.ndarray:
    """Keep mask of a cell of *n* points on its grid and lists (:func:`_grid_lists`; the grid holds the points):
    the elimination to *count* of its points with its halo points free (``kind`` (h,) 1: eliminated along),
    fixed (2: kept by a lower colour) or gone (0: removed by one), then *steps* relocation steps on the same
    grid."""
    if count == n or count == 0:
        return np.full(n, count == n)
    src = grid.order
    halo_row = src >= n
    state = np.ones(len(src), dtype=np.uint8)
    state[halo_row] = kind[src[halo_row] - n]
    state[grid.copy] = 0
    gone_rep = np.full(len(src), -1, dtype=np.int64)
    rows = np.flatnonzero(halo_row & (state == 0) & ~grid.copy)  # the gone points: represented by their nearest
    gone_rep[rows] = grid.nearest_kept((state != 0).astype(np.uint8), rows)  # point alive
    ones = np.ones(len(src))
    prio, rep = run_elimination(grid, lists, state, n, gone_rep, r_max, ALPHA, True, ones, ones, int(count), False)
    copy = np.zeros(len(src), dtype=bool)
    copy[src[grid.copy]] = True
    mine = prio[:n]
    mine[np.isnan(mine)] = np.inf  # exact copies
    keep = keep_lowest(mine, int(count))
    kept_halo = (np.isnan(prio[n:]) & ~copy[n:] & (kind == 1)) | (kind == 2)
    return relocate_on_grid(n, keep, kept_halo, r_max, int(steps), grid, rep) if steps else keep


def cell_cap(n: int, target: int, cell_points: int) -> int:
    """Points a cell holds at most: *cell_points*, more when fewer than ``MIN_KEPT`` would be kept in it."""
    return max(int(cell_points), math.ceil(MIN_KEPT * n / max(int(target), 1)))


def eliminate_cells(pts: np.ndarray, target: int, r_max: float, cells: tuple, steps: int,
                    threads: int, outer: tuple | None = None) -> np.ndarray:
    """Keep mask (n,) of exactly *target* points of *pts* (valid; r_max finite, 0 < target < n) split into
    *cells* (:func:`split_cells` of :func:`cell_cap` points), with *steps* relocation steps per cell,
    *threads* cells at once. *outer*: points (h, 3) around *pts* and their kinds (h,) uint8 (1 eliminated
    along, 2 fixed, 0 gone: :func:`eliminate_cell`), in the halo of every cell they come near."""
    n = len(pts)
    opts, okind = (np.zeros((0, 3)), np.zeros(0, dtype=np.uint8)) if outer is None else outer
    # the work runs on the points in cell order (Q: each cell's a block, positions instead of rows): read through
    # the rows, in the input's order (random for a large cloud), every read of the bands would miss the caches
    idx, starts, boxes, Q = cells
    ncell = len(starts) - 1
    size = np.diff(starts)
    cell = np.repeat(np.arange(ncell), size)  # the cell of every position
    margin = HALO_RADII * r_max
    near = _neighbours(boxes, margin)
    colour = cell_colours(np.r_[0, np.cumsum([len(x) for x in near])], np.concatenate(near + [np.zeros(0, int)]))
    own = [slice(starts[j], starts[j + 1]) for j in range(ncell)]
    ahead = target >= LISTS_AHEAD * n
    halos = [(np.zeros(0, dtype=np.int64),) * 2] * ncell

    def halo(j: int) -> tuple[np.ndarray, np.ndarray]:
        """The cell's halo: positions in the other cells' bands (set below, before any prepare), and rows of
        *outer*, within the margin."""
        lo, hi = boxes[j, 0] - margin, boxes[j, 1] + margin
        inner = _kk.halo_rows(Q, *bands, near[j], lo, hi)
        return inner, np.flatnonzero(np.all((opts >= lo) & (opts <= hi), axis=1))

    def prepare(j: int) -> tuple:
        halos[j] = h, o = halo(j)
        absent = np.r_[np.zeros(len(h), dtype=bool), okind[o] == 0]
        return _one_thread(_prepare, Q[own[j]], np.concatenate([take_rows(Q, h), opts[o]]), r_max, absent,
                           ahead)

    with ThreadPoolExecutor(max(1, int(threads))) as pool:
        # each cell's points a neighbour's halo may hold, all cells at once
        parts = list(pool.map(lambda j: _kk.band_rows(Q[own[j]], boxes[j], margin) + starts[j], range(ncell)))
        bands = (np.concatenate(parts), np.r_[0, np.cumsum([len(b) for b in parts])].astype(np.int64))
        prepared = list(pool.map(prepare, range(ncell)))
        distinct = np.array([p[3] for p in prepared])
        if distinct.sum() < target:  # exact copies fill the count, as in one elimination (they go first, so are
            distinct = size  # kept last)
        q = kept_counts(ladder_shares(np.array([p[2] for p in prepared]), target), distinct, target)
        keep = np.zeros(n, dtype=bool)  # by position
        done = {}

        def one(j: int) -> None:
            for i in near[j]:  # the lower colours' cells of its halo: their keep masks are final
                if colour[i] < colour[j]:
                    done[i].result()
            h, o = halos[j]
            lower = colour[cell[h]] < colour[j]
            kind = np.r_[np.where(lower, np.where(keep[h], 2, 0), 1).astype(np.uint8), okind[o]]
            grid, lists, _, _, state = prepared[j]
            if lists is None:
                lists = _one_thread(_lists, grid, state, r_max)
            keep[own[j]] = _one_thread(_finish, int(size[j]), grid, lists, kind, r_max, int(q[j]), steps)
            prepared[j] = None  # its grid and lists: no longer needed

        # colour by colour, largest first; a cell starts once the lower-colour cells of its halo are done (not
        # the whole lower colours). The pool takes the cells in this order, so a cell waits only for cells
        # started before it
        for j in apply_order(colour, size, range(ncell)):
            done[j] = pool.submit(one, j)
        for f in done.values():
            f.result()
    out = np.empty(n, dtype=bool)
    out[idx] = keep
    return out
