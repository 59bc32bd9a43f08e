"""One cell of the ``eliminate`` rule: its elimination with its halo, over k-d cells on threads.

:func:`eliminate_cell` is the per-cell kernel of every run of the rule
(:mod:`cloudsieve.engine.cell_scheme`); :func:`cloudsieve.core.eliminate.eliminate`
is it on the whole cloud without a halo. One elimination is sequential and, at
1 M points, memory-bound, so above ``cell_points`` points a cell is eliminated
over k-d cells on threads (:func:`eliminate_cells`):

1. **cells**: :func:`split_cells` cuts the longest side at the median, by value
   (independent of input order and unit; copies share a cell);
2. **counts**: each cell's size from greedy packings at radii about r_max
   (:mod:`.packing`), made exact integers by :func:`kept_counts`;
3. **elimination**, colour by colour (:func:`.colours.cell_colours`), each cell with
   its halo (points within 2.2 r_max of its box): lower colours' decisions fixed or
   gone, higher colours' points eliminated along.

The result depends on the points, the count and ``cell_points``, not on the
thread count nor (up to 50,000 points) the input order.
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
#: at least this share kept: every cell's lists are built ahead, with the packings; below it each
#: cell's lists are built when it runs and its packings walk the grid (less memory)
LISTS_AHEAD = 0.2


def split_cells(points: np.ndarray, cell_points: int, threads: int = 1) -> tuple[np.ndarray, np.ndarray,
                                                                              np.ndarray, np.ndarray]:
    """Split *points* (n, 3) into k-d cells of at most *cell_points* points (independent of *threads*).

    Returns idx (n,) int64 (points cell by cell, ascending inside each), starts (C + 1,)
    (cell c holds ``idx[starts[c]:starts[c + 1]]``), boxes (C, 2, 3) (lower and upper
    corner of each cell's region, +-inf outside; the regions tile space), and ordered
    ``points[idx]``.
    """
    n = len(points)
    # rows and points move between two pairs of buffers, cut after cut; a cell's range is copied back once
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
    """Keep mask (n,) bool of one cell: exactly ``count`` (in [0, n]) of ``points`` (n, 3), by elimination with its halo, then relocation.

    ``r_max``: the cloud's radius. ``decided`` halo points (h,) weigh as fixed when kept
    (``halo_keep``) and as gone when removed; the others are eliminated along. Then
    ``steps`` steps of :func:`relocate` on the same grid. Above ``cell_points`` points
    (None: never; :func:`cell_cap`) as :func:`eliminate_cells`. In stages
    (:mod:`.staged`) when ``staged``; None: when the count is below 1 in
    :data:`.staged.STAGED_BELOW` of the distinct points.
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
    """:func:`eliminate_cell` as one elimination on valid input; *kind* (h,) uint8: 1 free, 2 fixed, 0 gone."""
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
    """The grid of [own, halo] (cells of 2 r_max) and its state: all alive but copies and halo points ``absent``."""
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
    """The grid of [own, halo] and its neighbour lists within 2 r_max, without the halo points ``absent``."""
    grid, state = _grid_state(own, halo, r_max, absent)
    return grid, _lists(grid, state, r_max)


def _prepare(own: np.ndarray, halo: np.ndarray, r_max: float, absent=None, ahead: bool = True) -> tuple:
    """A cell's preparation before its halo is decided: grid and state (:func:`_grid_state`),
    lists when ``ahead`` (else None), packing sizes along ``LADDER`` (:mod:`.packing`), distinct points.
    """
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
    """Keep mask of a cell of *n* points on its grid and lists (:func:`_grid_lists`).

    Eliminates to *count* with halo points free (``kind`` 1), fixed (2) or gone (0),
    then *steps* relocation steps.
    """
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
    prio, rep = run_elimination(grid, lists, state, n, gone_rep, r_max, int(count), keys_left=False)
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
    """Keep mask (n,) of exactly *target* points of valid *pts* (0 < target < n), over *cells* (:func:`split_cells`).

    *steps* relocation steps per cell, *threads* cells at once; *outer*: points (h, 3)
    around *pts* and their kinds (h,) uint8, in the halo of the cells they come near.
    """
    n = len(pts)
    opts, okind = (np.zeros((0, 3)), np.zeros(0, dtype=np.uint8)) if outer is None else outer
    # work on positions in cell order (Q): rows in input order would miss the caches
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
        """The cell's halo: positions in other cells' bands, and rows of *outer*, within the margin."""
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
            prepared[j] = None

        # colour by colour, largest first; a cell waits only for the lower-colour cells of its halo
        for j in apply_order(colour, size, range(ncell)):
            done[j] = pool.submit(one, j)
        for f in done.values():
            f.result()
    out = np.empty(n, dtype=bool)
    out[idx] = keep
    return out
