"""The eliminate cells stage (:mod:`.cell_scheme`) with class policies (:mod:`.class_policy`): a group at a time.

Shares and counts are per group, each group's counts summing exactly to its
target; a cell eliminates its groups in order, each with the rest as fixed
context (docs/architecture.md, "Class policies"). A cell reads only its own
points and the final decisions of lower colours: nothing depends on the
worker count.
"""

from __future__ import annotations

import numpy as np

from ..core.packing import LADDER
from .class_policy import WHOLE

__all__ = ["group_share", "group_counts", "group_keep"]

#: columns of a group's share: its distinct points, then its packing sizes
_COLUMNS = 1 + len(LADDER)


def group_share(io, task, core: np.ndarray, dependents: dict) -> tuple[np.ndarray, np.ndarray, int]:
    """The cell's groups stored (``io.put_groups``) and its share row: points kept whole, then per group
    its distinct points and packing sizes; its band (over all its points) and its exact copies."""
    from .cell_work import task_threads, cell_share
    from .halo import band_mask

    groups = np.asarray(task.params["lookup"], dtype=np.int8)[io.classes(task)]
    io.put_groups(task, groups)
    r_max = float(task.params["r_max"])
    row, copies = [float((groups == WHOLE).sum())], 0
    for g in range(int(task.params["groups"])):  # no dependents: a group's band is not needed
        own = groups == g
        sizes, distinct, _ = cell_share(core[own], r_max, task.centers, task.cell, {}, task.margin, task_threads(task),
                                        ladder=task.params["ladder"])
        row += [float(distinct), *sizes]
        copies += int(own.sum()) - distinct
    # the band over every point of the cell, as without policies
    band = np.flatnonzero(band_mask(core, {**dependents, task.cell: task.centers[task.cell]}, task.cell, dependents,
                                    task.margin))
    return np.array(row), band, copies


def group_counts(share: np.ndarray, targets: np.ndarray, r_max: float) -> tuple[np.ndarray, list, np.ndarray]:
    """Counts (P, G) from the share rows (P, 1 + G (1 + L)), column g summing to ``targets[g]``; whether each
    group runs in stages; each cell's distinct points (the whole ones included)."""
    from .cell_work import cell_counts

    distinct = share[:, 0].astype(np.int64)
    q, staged = np.zeros((len(share), len(targets)), dtype=np.int64), []
    for g, target in enumerate(targets):
        cols = share[:, 1 + g * _COLUMNS : 1 + (g + 1) * _COLUMNS]
        d = cols[:, 0].astype(np.int64)
        q[:, g], s = cell_counts(cols[:, 1:], d, int(target), r_max)
        staged.append(s)
        distinct = distinct + d
    return q, staged, distinct


def group_keep(io, task, core: np.ndarray, counts: list, colours: dict) -> np.ndarray:
    """The keep mask (n,) of a cell, its groups eliminated in order to *counts* (G,), the whole ones kept."""
    from .cell_work import task_threads, cell_keep, halo_rows

    groups = np.asarray(io.groups(task, len(core)))
    keep = groups == WHOLE
    sizes = [int((groups == g).sum()) for g in range(len(counts))]
    if not any(0 < q < m for q, m in zip(counts, sizes)):  # nothing to eliminate: no halo
        for g, q in enumerate(counts):
            keep[groups == g] = q >= sizes[g]
        return keep
    points, rows, fixed = halo_rows(io, task, colours)
    hgroup = np.asarray(io.groups_at(rows)) if len(rows) else np.zeros(0, dtype=np.int8)
    hkeep = np.zeros(len(points), dtype=bool)
    if fixed.any():  # their final decisions
        hkeep[fixed] = io.keep_at(rows[fixed])
    r_max, staged = float(task.params["r_max"]), task.params.get("staged") or [None] * len(counts)
    for g, q in enumerate(counts):
        own = groups == g
        if not 0 < q < sizes[g]:
            keep[own] = q >= sizes[g]
            continue
        rest = ~own  # the cell's other points: decided (groups before g), else kept (whole, groups after g)
        other = hgroup != g  # the halo's other groups: fixed; decided in lower colours, else kept
        halo = (np.concatenate([core[rest], points]), np.r_[np.ones(int(rest.sum()), dtype=bool), fixed | other],
                np.r_[keep[rest] | (groups[rest] > g), np.where(fixed, hkeep, other)])
        keep[own] = cell_keep(core[own], int(q), r_max, halo, task_threads(task), staged[g],
                              task.params.get("keep_duplicates"))
    return keep
