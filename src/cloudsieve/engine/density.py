"""The density target of the eliminate rule (``density``, ``density_cell``): :class:`DensityTarget`.

An area of side R holding more than F = floor(D R^2) points keeps exactly F,
the others all theirs. Each (area, cell) pair gets an exact quota by largest
remainder (:func:`area_quotas`) and a cell eliminates its dense areas in turn
(:func:`density_keep`), as :mod:`.class_cells` a group (docs/architecture.md,
"Density target"). Nothing depends on the worker count.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DensityTarget", "Sorted", "area_keys", "area_counts", "area_quotas", "density_keep",
           "area_counts_task", "run_area_counts"]

#: an area's column index is shifted by this many bits in its key (rows below 2^31 in magnitude)
_SHIFT = 32


#: a cube's column, row and layer are shifted by 2^20 and packed in 21 bits each
_BITS, _BIAS = 21, 1 << 20


def area_keys(xyz: np.ndarray, side: float, dims: int = 2) -> np.ndarray:
    """Each point's area (n,) int64: floor(x / side) * 2^32 + floor(y / side); keys sort as (column, row).
    With *dims* 3 its cube: column, row and layer (floor(z / side)) + 2^20 in 21 bits each; InputFormatError
    for a cube 2^20 or more from the origin on an axis."""
    ij = np.floor(np.asarray(xyz)[:, :dims] / float(side)).astype(np.int64)
    if dims == 2:
        return (ij[:, 0] << _SHIFT) + ij[:, 1]
    if len(ij) and (int(ij.min()) < -_BIAS or int(ij.max()) >= _BIAS):
        from ..errors import InputFormatError

        raise InputFormatError(f"density_3d: cubes of side {side:g} reach {int(np.abs(ij).max()):,} cubes from "
                               f"the origin on an axis, more than {_BIAS:,}: use a larger density_cell")
    ij += _BIAS
    return (ij[:, 0] << 2 * _BITS) + (ij[:, 1] << _BITS) + ij[:, 2]


def area_counts(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The areas present (sorted) and their points."""
    return np.unique(keys, return_counts=True)


def merge_counts(parts) -> tuple[np.ndarray, np.ndarray]:
    """Sum (keys, counts) pairs into one, keys sorted."""
    parts = list(parts)
    if not parts:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    keys = np.concatenate([k for k, _ in parts])
    counts = np.concatenate([c for _, c in parts])
    uniq, inv = np.unique(keys, return_inverse=True)
    return uniq, np.bincount(inv, weights=counts, minlength=len(uniq)).astype(np.int64)


class DensityTarget:
    """*density* D points per square unit in areas of side *side*: ``floor`` F = floor(D R^2) per area; with
    *dims* 3 per cubic unit in cubes, F = floor(D R^3)."""

    def __init__(self, density: float, side: float, dims: int = 2) -> None:
        from ..params import density_floor

        self.density, self.side, self.dims = float(density), float(side), int(dims)
        self.floor = density_floor(self.density, self.side, self.dims)

    @classmethod
    def from_options(cls, opts: dict) -> "DensityTarget | None":
        """The target of validated *opts*, None without ``density``."""
        from ..params import DENSITY_CELL

        side = DENSITY_CELL if opts.get("density_cell") is None else opts["density_cell"]
        dims = 3 if opts.get("density_3d") else 2
        return None if opts.get("density") is None else cls(opts["density"], side, dims)

    def target(self, counts: np.ndarray) -> int:
        """Points kept in all from the areas' points: min(points, F) summed."""
        return int(np.minimum(np.asarray(counts, dtype=np.int64), self.floor).sum())

    def report(self, before: tuple, after: tuple) -> dict:
        """The summary's ``density``: the areas' points per square unit, min/median/p95/max over the areas holding
        points, before and after; areas and areas thinned; ``floor`` and ``side``."""
        area = self.side ** self.dims
        _, n0 = before
        _, n1 = after

        def stats(counts):
            d = np.asarray(counts, dtype=np.float64) / area
            q = np.percentile(d, [0, 50, 95, 100]) if len(d) else np.zeros(4)
            return dict(zip(("min", "median", "p95", "max"), (round(float(v), 9) for v in q)))

        return {"density": self.density, "side": self.side, "dims": self.dims, "floor": self.floor,
                "areas": int(len(n0)),
                "thinned": int((np.asarray(n0) > self.floor).sum()), "before": stats(n0), "after": stats(n1)}


def area_quotas(per_cell: list, floor: int) -> list[np.ndarray]:
    """Each cell's quota per area (aligned with its keys) from *per_cell* [(keys, counts)] of every cell.

    An area of N <= *floor* points keeps them all; else its *floor* points are
    split among its cells in proportion to their points: floor(F n_j / N)
    each, the rest one by one to the largest remainders F n_j mod N, ties to
    the lower cell. Each quota is at most the cell's points."""
    sizes = [len(k) for k, _ in per_cell]
    cell = np.repeat(np.arange(len(per_cell), dtype=np.int64), sizes)
    keys = np.concatenate([k for k, _ in per_cell]) if per_cell else np.zeros(0, dtype=np.int64)
    n = np.concatenate([c for _, c in per_cell]).astype(np.int64) if per_cell else np.zeros(0, dtype=np.int64)
    uniq, inv = np.unique(keys, return_inverse=True)
    total = np.bincount(inv, weights=n, minlength=len(uniq)).astype(np.int64)[inv]
    dense = total > floor
    quota = n.copy()
    share = floor * n  # F n_j < 2^63 for any cloud that fits a store
    base = np.where(dense, share // np.maximum(total, 1), n)
    rem = np.where(dense, share % np.maximum(total, 1), 0)
    quota[:] = base
    left = np.bincount(inv, weights=np.where(dense, base, 0), minlength=len(uniq)).astype(np.int64)
    short = (floor - left)[inv]  # points each dense area still gives out
    # by area, then largest remainder, then lower cell: the first `short` pairs of a dense area get one more
    order = np.lexsort((cell, -rem, inv))
    first = np.r_[0, np.flatnonzero(np.diff(inv[order])) + 1]
    rank = np.arange(len(order)) - np.repeat(first, np.diff(np.r_[first, len(order)]))
    more = np.zeros(len(order), dtype=bool)
    more[order] = dense[order] & (rank < short[order])
    quota += more
    return np.split(quota, np.cumsum(sizes)[:-1]) if per_cell else []


class Sorted:
    """Points by area key (:func:`area_keys`)."""

    def __init__(self, keys: np.ndarray, dims: int = 2) -> None:
        self.order = np.argsort(keys, kind="stable")
        self.keys, self.dims = keys[self.order], dims

    def rows(self, key: int, reach: int) -> np.ndarray:
        """The rows (ascending) of the points in the areas (cubes) at most *reach* steps from area *key* on
        each axis."""
        steps = np.arange(-reach, reach + 1, dtype=np.int64)
        if self.dims == 2:
            col = int(key) >> _SHIFT
            last = int(key) - (col << _SHIFT)
            firsts = (col + steps) << _SHIFT
        else:  # each (column, row) around: a range of layers
            col, row, last = int(key) >> 2 * _BITS, (int(key) >> _BITS) & (_BIAS * 2 - 1), int(key) & (_BIAS * 2 - 1)
            firsts = (((col + steps)[:, None] << 2 * _BITS) + ((row + steps)[None, :] << _BITS)).ravel()
        starts = np.searchsorted(self.keys, firsts + last - reach, "left")
        ends = np.searchsorted(self.keys, firsts + last + reach, "right")
        parts = [self.order[s:e] for s, e in zip(starts, ends) if e > s]
        return np.unique(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.int64)  # ranges may meet at an edge


def density_keep(io, task, core: np.ndarray, quotas, colours: dict) -> np.ndarray:
    """The keep mask (n,) of a cell, each dense area eliminated to its quota (*quotas*, aligned with the
    cell's sorted areas) in key order, with the rest as context: the cell's other points (the areas already
    run by their decisions, the others as kept), the halo's points of other areas or of lower-colour cells as
    fixed, the area's own points of higher-colour cells eliminated along; each point within 2.2 r_max of the
    area's points."""
    from ..core.eliminate_cells import HALO_RADII
    from .cell_work import task_threads, cell_keep, halo_rows

    side, r_max = float(task.params["density_cell"]), float(task.params["r_max"])
    dims = int(task.params.get("density_dims") or 2)
    keys = area_keys(core, side, dims)
    uniq, inv = np.unique(keys, return_inverse=True)
    quotas = np.asarray(quotas, dtype=np.int64)
    sizes = np.bincount(inv, minlength=len(uniq))
    keep = np.ones(len(core), dtype=bool)
    dense = np.flatnonzero(quotas < sizes)
    if not len(dense):
        return keep
    points, rows, fixed = halo_rows(io, task, colours)
    hkeep = np.ones(len(points), dtype=bool)  # the higher colours' points weigh as kept
    if fixed.any():  # the lower colours' final decisions
        hkeep[fixed] = io.keep_at(rows[fixed])
    hkeys = area_keys(points, side, dims) if len(points) else np.zeros(0, dtype=np.int64)
    margin = HALO_RADII * r_max if np.isfinite(r_max) else 0.0
    reach = int(np.ceil(margin / side))  # areas of context on each side
    cells_by_area, halo_by_area = Sorted(keys, dims), Sorted(hkeys, dims)
    for a in dense:
        own = cells_by_area.rows(uniq[a], 0)
        if quotas[a] == 0:
            keep[own] = False
            continue
        mine = core[own]
        lo, hi = mine[:, :dims].min(axis=0) - margin, mine[:, :dims].max(axis=0) + margin
        near = cells_by_area.rows(uniq[a], reach)
        near = near[(keys[near] != uniq[a]) & np.all((core[near, :dims] >= lo) & (core[near, :dims] <= hi), axis=1)]
        h = halo_by_area.rows(uniq[a], reach)
        h = h[np.all((points[h, :dims] >= lo) & (points[h, :dims] <= hi), axis=1)]
        along = ~fixed[h] & (hkeys[h] == uniq[a])  # eliminated along
        halo = (np.concatenate([core[near], points[h]]), np.r_[np.ones(len(near), dtype=bool), ~along],
                np.r_[keep[near], hkeep[h] & ~along])
        keep[own] = cell_keep(mine, int(quotas[a]), r_max, halo, task_threads(task), None,
                              task.params.get("keep_duplicates"))
    return keep


def area_counts_task(store_path: str, start: int, stop: int, side: float, dims: int, mask: str | None) -> tuple:
    """Task: the areas (sorted keys) of ``[start, stop)`` and their points, only those of *mask* when given."""
    from ..store import PointStore

    st = PointStore.open(store_path)
    xyz = st.decode_xyz(np.asarray(st.array("xyz")[start:stop]))
    if mask is not None:
        xyz = xyz[np.asarray(st.group[mask][start:stop], dtype=bool)]
    return area_counts(area_keys(xyz, side, dims))


def run_area_counts(store, runner, density: DensityTarget, mask: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The areas of *density* in *store* (of *mask*'s points when given) and their points, a task per chunk."""
    n, step = store.count, store.chunk_size
    args = [(store.path, s, min(s + step, n), density.side, density.dims, mask) for s in range(0, n, step)]
    return merge_counts(runner(area_counts_task, args, "density: areas"))
