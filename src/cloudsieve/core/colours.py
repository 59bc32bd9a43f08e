"""Colours of the cells: no two cells that share a halo get the same colour.

Pass 2 of ``eliminate`` (:mod:`cloudsieve.engine.cell_scheme`, :mod:`.eliminate_cells`)
runs colour by colour, so cells of one colour run in parallel. The greedy colouring
is a pure function of the partition, so a resumed run needs no record of it.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidParameterError

__all__ = ["halo_graph", "cell_colours", "apply_order", "readers"]


def halo_graph(halo_ptr, halo_src) -> tuple[np.ndarray, np.ndarray]:
    """The symmetric neighbour lists of the halo CSR, without self loops.

    Returns
    -------
    ptr : ndarray (P + 1,), int64
    nbr : ndarray (e,), int64
        Neighbours of cell i, increasing: ``nbr[ptr[i]:ptr[i + 1]]``.
    """
    ptr = np.asarray(halo_ptr, dtype=np.int64)
    src = np.asarray(halo_src, dtype=np.int64)
    if ptr.ndim != 1 or len(ptr) < 1 or ptr[0] != 0 or np.any(np.diff(ptr) < 0) or ptr[-1] != len(src):
        raise InvalidParameterError(f"halo_ptr must be a CSR pointer from 0 to len(halo_src)={len(src)}, "
                                    f"got shape {ptr.shape}")
    p = len(ptr) - 1
    if len(src) and (src.min() < 0 or src.max() >= p):
        raise InvalidParameterError(f"halo_src must hold cells in [0, {p}), got {src.min()}..{src.max()}")
    rows = np.repeat(np.arange(p, dtype=np.int64), np.diff(ptr))
    pairs = np.concatenate([np.c_[rows, src], np.c_[src, rows]])
    pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)  # sorted by (i, j)
    out = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=p), out=out[1:])
    return out, pairs[:, 1].copy()


def cell_colours(halo_ptr, halo_src) -> np.ndarray:
    """Greedy colouring of :func:`halo_graph`: by decreasing degree, then id; lowest free colour.

    >>> cell_colours([0, 1, 3, 4], [1, 0, 2, 1]).tolist()  # a path 0 - 1 - 2
    [1, 0, 1]
    """
    ptr, nbr = halo_graph(halo_ptr, halo_src)
    p = len(ptr) - 1
    deg = np.diff(ptr)
    colour = np.full(p, -1, dtype=np.int64)
    for i in np.lexsort((np.arange(p), -deg)):  # a loop over cells (P), not points
        used = colour[nbr[ptr[i] : ptr[i + 1]]]
        taken = np.zeros(len(used) + 1, dtype=bool)
        taken[used[(used >= 0) & (used <= len(used))]] = True
        colour[i] = int(np.argmin(taken))
    return colour


def apply_order(colours: np.ndarray, counts, cells) -> list[int]:
    """*cells* colour by colour, each colour's largest (*counts*) first, ties by id."""
    return sorted((int(j) for j in cells), key=lambda j: (int(colours[j]), -int(counts[j]), j))


def readers(halo_ptr, halo_src) -> list[np.ndarray]:
    """For each cell, the cells that list it among their halo sources, ascending (the transpose of the CSR)."""
    halo_ptr, halo_src = np.asarray(halo_ptr), np.asarray(halo_src)
    owner = np.repeat(np.arange(len(halo_ptr) - 1), np.diff(halo_ptr))
    order = np.lexsort((owner, halo_src))
    ends = np.cumsum(np.bincount(halo_src, minlength=len(halo_ptr) - 1))
    return np.split(owner[order], ends[:-1])
