"""Partition label + bucket: one task per input chunk.

Each point gets its nearest cell centre (ties to the lower index,
:mod:`cloudsieve.core.kernels.closest`); the chunk sorted by cell (stable)
goes to the chunk's own row of ``partition/xyz``, so nothing is sorted
globally or written to another task's chunk. The same pass lists the halo
pairs from each point's ``HALO_NEIGHBOURS`` nearest centres (:mod:`.halo`).
"""

from __future__ import annotations

import numpy as np

from ..chunk import take_rows
from ..core.kernels.closest import nearest_sites, site_tree
from ..core.kernels.scatter import group_rows
from ..core.kernels.threads import Chunks

__all__ = ["label_block", "label_points", "label_chunk", "HALO_NEIGHBOURS", "LABEL_BLOCK"]

#: nearest centres tested per point when listing halo sources
HALO_NEIGHBOURS = 5
#: points labelled at once inside a chunk task (bounds the k-d tree query arrays)
LABEL_BLOCK = 131072


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


def label_block(centers: np.ndarray, xyz: np.ndarray, margin: float, tree: tuple | None = None, halo: bool = True):
    """Cell of each point (n,) int64 (nearest centre, ties to the lower index) and halo pairs (q, 2) int64.

    A pair (i, j): some point of cell j lies within *margin* of the bisector
    of c_i and c_j. The test uses the tree's distances, ``s_ij(z) = (|z -
    c_i|^2 - |z - c_j|^2) / (2 |c_i - c_j|)``, with a slack of 1e-6 of the
    margin so the candidates stay a superset of
    :func:`cloudsieve.engine.halo.halo_distance`'s. ``halo=False`` queries
    only 2 centres (more on ties) and returns no pairs. *tree*:
    :func:`~cloudsieve.core.kernels.closest.site_tree` of *centers*, built when None.
    """
    p = len(centers)
    none = np.empty((0, 2), dtype=np.int64)
    if p == 1:
        return np.zeros(len(xyz), dtype=np.int64), none
    if tree is None:
        tree = site_tree(centers)
    kq = min(p, HALO_NEIGHBOURS + 1)
    # 2 nearest centres for all; kq only where the second is close enough for a pair (or, without halo, tied)
    bound = 2.0 * margin * (1 + 1e-6) + 1e-12 if halo else 0.0
    d, nn = nearest_sites(tree, xyz, 2)
    labels = nn[:, 0].astype(np.int64)
    near = np.flatnonzero((d[:, 1] - d[:, 0]) <= bound)
    if kq > 2 and len(near):
        d, nn = nearest_sites(tree, xyz[near], kq)
    else:
        d, nn = d[near], nn[near]
    labels[near] = _lowest_tied(d, nn)
    if not halo:
        return labels, none
    d2 = d * d
    # every column but the label's (column 0 too: on a tie the label may be a later column)
    other = nn.astype(np.int64)
    # cheap bound first: s_ij <= margin needs d_i - d_j <= 2 margin (|c_i - c_j| >= d_i - d_j)
    cand = (d - d[:, :1]) <= bound
    rows, cols = np.nonzero(cand)
    if len(rows):
        i = other[rows, cols]
        j = labels[near[rows]]
        diff = centers[i] - centers[j]
        cd = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        with np.errstate(invalid="ignore", divide="ignore"):  # i == j gives 0/0, masked out below
            s = (d2[rows, cols] - d2[rows, 0]) / (2.0 * cd)
        hit = (i != j) & (s <= margin * (1 + 1e-6) + 1e-12)
        keys = np.unique(i[hit] * p + j[hit])
        pairs = np.stack([keys // p, keys % p], axis=1)
    else:
        pairs = none
    return labels, pairs


def label_points(centers: np.ndarray, xyz: np.ndarray, margin: float, halo: bool = True,
                 threads: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """:func:`label_block` over blocks of ``LABEL_BLOCK`` points on *threads* threads: labels (n,) and distinct pairs (q, 2)."""
    tree = site_tree(centers) if len(centers) > 1 else None  # one cell: no tree
    labels = np.empty(len(xyz), dtype=np.int64)

    def block(a: int) -> np.ndarray:
        labels[a : a + LABEL_BLOCK], got = label_block(centers, xyz[a : a + LABEL_BLOCK], margin, tree, halo)
        return got

    starts = range(0, len(xyz), LABEL_BLOCK)
    with Chunks(min(int(threads), len(starts))) as chunks:  # the tree's queries release the GIL
        pairs = chunks.each(block, starts)
    return labels, np.unique(np.concatenate([np.empty((0, 2), dtype=np.int64), *pairs], axis=0), axis=0)


def label_chunk(
    store_path: str, chunk: int, start: int, stop: int, margin: float, halo: bool = True
) -> tuple[np.ndarray, int]:
    """Label + bucket task for input chunk *chunk* (points ``[start, stop)``).

    Reads the centres from the store (passing P x 3 per task would cost
    O(n_chunks x P)). Writes ``partition/cell[start:stop]``,
    ``partition/xyz[chunk]`` (sorted by cell, stable) and the nonzero runs
    (cell, count) into the scratch ``partition/label_runs[chunk]`` for
    :func:`cloudsieve.engine.runs.index_runs`. Returns the chunk's distinct
    halo pairs (q, 2) and its count of cells.
    """
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    g = st.group
    centers = np.asarray(g["partition/centers"][:])
    raw = np.asarray(st.array("xyz")[start:stop])  # stored rows (LAS integers stay so)
    xyz = st.decode_xyz(raw)
    n = len(xyz)
    labels, pairs = label_points(centers, xyz, margin, halo)
    order, bounds = group_rows(labels, len(centers))  # cell by cell, input order within each
    sizes = np.diff(bounds)
    cells = np.flatnonzero(sizes)
    counts = sizes[cells]
    g["partition/cell"][start:stop] = labels.astype(np.int32)
    g["partition/xyz"][chunk, :n] = take_rows(raw if st.xyz_scale is not None else xyz, order)
    if len(cells):
        g["partition/label_runs"][chunk, : len(cells)] = np.stack([cells, counts], axis=1).astype(np.int64)
    return pairs, int(len(cells))
