"""The exact global cut over the stored scores of all cells: a threshold T and per-cell tie quotas.

:func:`cloudsieve.engine.threshold.global_threshold` finds T on the
``target`` rule's scores through log10 histograms and is exact only up to
ties (equal scores go or stay together). The ``eliminate`` rule needs the
exact count, so :func:`exact_cut` picks, among the scores stored in
``simplify/score_cells`` (lower goes first), the ``remove``-th smallest T and
then says how many of the points with score == T each cell removes.

Selection: every float64 score maps to a 64-bit key with the same order
(:func:`sortable_keys`); rounds of per-cell histograms of the next
``KEY_BITS`` bits of the keys (one small task per cell, summed in the driver:
chunk / combine / aggregate) narrow the key of T bit by bit until its bin
holds at most ``GATHER_MAX`` scores, which are gathered and sorted, or until
all 64 bits are fixed. Every sum is over integers: T does not depend on the
scheduler or on task order, and it is exact for any scores (negative, zero,
±inf), not only the positive range of the histograms.

Ties: with ``below`` scores < T, ``remove - below`` of the scores == T go,
given to the cells in increasing cell id (each cell up to all of its own),
and inside a cell to its points of score == T in increasing index (its
points are in input order): ties broken by cell, then by index within the
cell. Deterministic, and the driver holds arrays of size P only
(:class:`Cut`). A cell's keep mask is then :func:`keep_mask`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Cut", "exact_cut", "keep_mask", "sortable_keys", "key_value", "key_hist_task", "keys_task",
           "KEY_BITS", "GATHER_MAX"]

#: bits of the key fixed per histogram round (2**KEY_BITS bins per cell)
KEY_BITS = 11
#: gather the scores of T's bin once it holds at most this many
GATHER_MAX = 200_000
_SIGN = np.uint64(1 << 63)


def sortable_keys(scores) -> np.ndarray:
    """uint64 keys in the order of the float64 *scores* (-0.0 counts as 0.0).

    Returns
    -------
    ndarray of shape (n,), uint64
        ``a < b`` exactly when ``key(a) < key(b)``.
    """
    b = (np.asarray(scores, dtype=np.float64) + 0.0).view(np.uint64)  # + 0.0: -0.0 becomes 0.0
    return np.where((b & _SIGN) != 0, ~b, b | _SIGN)


def key_value(key: int) -> float:
    """The float64 whose :func:`sortable_keys` key is *key*."""
    k = np.uint64(key)
    b = (k & ~_SIGN) if (k & _SIGN) else ~k
    return float(np.array([b], dtype=np.uint64).view(np.float64)[0])


def _keys(store_path: str, region: int, n: int, prefix: int, used: int) -> np.ndarray:
    """The keys of one cell's stored scores whose first *used* bits are *prefix*."""
    from ..store import PointStore

    st = PointStore.open(store_path, "r")
    k = sortable_keys(np.asarray(st.group["simplify/score_cells"][region : region + n]))
    if used:
        k = k[(k >> np.uint64(64 - used)) == np.uint64(prefix)]
    return k


def key_hist_task(store_path: str, region: int, n: int, prefix: int, used: int, bits: int) -> np.ndarray:
    """Histogram of the next *bits* key bits of one cell's scores with key prefix *prefix* (a task).

    Returns
    -------
    ndarray of shape (2**bits,), int64
    """
    k = _keys(store_path, region, n, prefix, used)
    digit = (k >> np.uint64(64 - used - bits)) & np.uint64((1 << bits) - 1)
    return np.bincount(digit.astype(np.int64), minlength=1 << bits).astype(np.int64)


def keys_task(store_path: str, region: int, n: int, prefix: int, used: int) -> np.ndarray:
    """The keys of one cell's scores with prefix *prefix* (few, by construction; a task).

    Returns
    -------
    ndarray of shape (k,), uint64
    """
    return _keys(store_path, region, n, prefix, used)


@dataclass
class Cut:
    """The global cut: remove every score < T, and ``quotas[j]`` of cell j's scores == T.

    Attributes
    ----------
    threshold : float
        T (-inf when nothing is removed).
    quotas : ndarray of shape (P,), int64
        Points of score == T cell j removes: its lowest-index ones.
    equal : ndarray of shape (P,), int64
        Points of score == T in cell j.
    removed : int
        Points removed in all.
    """

    threshold: float
    quotas: np.ndarray
    equal: np.ndarray
    removed: int


def exact_cut(store, part, regions: np.ndarray, runner, remove: int, gather_max: int = GATHER_MAX) -> Cut:
    """The cut that removes exactly *remove* points (all when *remove* >= N) of lowest stored score.

    Parameters
    ----------
    store : PointStore
    part : Partition
    regions : ndarray of shape (P,), int64
        Start of each cell's region in ``simplify/score_cells``.
    runner : Runner
    remove : int
    gather_max : int
        Gather the scores of T's bin once it holds at most this many (0:
        histograms down to the last bit).

    Returns
    -------
    Cut
    """
    counts = part.cell_counts
    p = part.n_cells
    cells = np.flatnonzero(counts > 0)
    quotas = np.zeros(p, dtype=np.int64)
    equal = np.zeros(p, dtype=np.int64)
    total = int(counts.sum())
    remove = min(int(remove), total)
    if remove <= 0:
        return Cut(-math.inf, quotas, equal, 0)

    def args(*extra):
        return [(store.path, int(regions[j]), int(counts[j]), *extra) for j in cells]

    prefix, used, below = 0, 0, 0
    while True:
        bits = min(KEY_BITS, 64 - used)
        hists = np.stack(runner(key_hist_task, args(prefix, used, bits), "cells: cut"))
        cum = np.cumsum(hists.sum(axis=0))
        b = int(np.searchsorted(cum, remove - below, side="left"))  # T's bin: the first reaching the count
        below += int(cum[b - 1]) if b else 0
        prefix, used = (prefix << bits) | b, used + bits
        if used == 64:  # every score of the bin is T
            key, eq = prefix, hists[:, b]
            break
        if int(hists[:, b].sum()) <= gather_max:
            parts = runner(keys_task, args(prefix, used), "cells: cut")
            inside = np.sort(np.concatenate(parts))
            key = int(inside[remove - below - 1])
            below += int(np.searchsorted(inside, np.uint64(key), side="left"))
            eq = np.array([int((q == np.uint64(key)).sum()) for q in parts], dtype=np.int64)
            break
    equal[cells] = eq
    before = np.cumsum(equal) - equal  # ties of the cells of lower id
    quotas[:] = np.clip(remove - below - before, 0, equal)
    return Cut(key_value(key), quotas, equal, remove)


def keep_mask(scores: np.ndarray, threshold: float, quota: int) -> np.ndarray:
    """Keep mask of one cell under a :class:`Cut`: score > T, and its scores == T after the first *quota*.

    Returns
    -------
    ndarray of shape (n,), bool
    """
    s = np.asarray(scores)
    keep = s > threshold
    keep[np.flatnonzero(s == threshold)[int(quota):]] = True
    return keep
