"""Compiled kernels of the packing counts (numba; private, inputs assumed valid).

Two walks of the same neighbours: over the grid (:func:`packing_counts`, the
engine's share task, no lists) and over the lists (:func:`packing_from_lists`, the
in-memory cells). The loops stay written out: a shared helper makes the grid walk
markedly slower. Grid arguments as in :mod:`.grid`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _blocked(P, i, j, m, r2, full):
    """Packings among ``m`` (a bit each) that member j closes to point i: those whose radius sqrt(r2[k]) exceeds their distance."""
    dx = P[j, 0] - P[i, 0]
    dy = P[j, 1] - P[i, 1]
    dz = P[j, 2] - P[i, 2]
    d2 = dx * dx + dy * dy + dz * dz
    k = 0  # the radii d2 is not within: within radius k, so within every larger one (none: full << L is 0 in m)
    for t in range(len(r2)):  # counted without a branch (which radius is a coin toss for the processor)
        k += d2 >= r2[t]
    return m & (full << k)


@njit(cache=True, nogil=True, inline="always")
def _join(i, blocked, full, mask, counts):
    """Point i joins every packing not ``blocked``."""
    free = full & ~blocked
    mask[i] = free
    for k in range(len(counts)):
        counts[k] += (free >> k) & 1


@njit(cache=True, nogil=True)
def packing_counts(P, cell, cstart, nstart, ncells, skip, r2):
    """Sizes (L,) of greedy packings at radii sqrt(r2) (increasing, at most 8), in one pass in grid order.

    A point joins packing k when no member is closer than sqrt(r2[k]); ``skip`` rows
    join none. Only members are compared (listed per cell in ``joined``), so a dense
    cell with few members costs its members.
    """
    full = (1 << len(r2)) - 1
    mask = np.zeros(len(P), dtype=np.uint8)
    counts = np.zeros(len(r2), dtype=np.int64)
    joined = np.empty(len(P), dtype=np.int64)
    cnt = np.zeros(len(cstart), dtype=np.int64)
    for i in range(len(P)):
        if skip[i]:
            continue
        blocked = 0
        c = cell[i]
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            # only rows visited before i can be in a packing: the members listed so far
            for u in range(cstart[cc], cstart[cc] + cnt[cc]):
                j = joined[u]
                m = mask[j] & ~blocked
                if m != 0:
                    blocked |= _blocked(P, i, j, m, r2, full)
            if blocked == full:
                break
        _join(i, blocked, full, mask, counts)
        if mask[i] != 0:
            joined[cstart[c] + cnt[c]] = i
            cnt[c] += 1
    return counts


@njit(cache=True, nogil=True)
def packing_from_lists(P, nptr, nbr, join, r2):
    """:func:`packing_counts` of rows with ``join`` != 0 over the lists of :mod:`.neighbours` (same packings, no grid walk)."""
    full = (1 << len(r2)) - 1
    mask = np.zeros(len(P), dtype=np.uint8)
    counts = np.zeros(len(r2), dtype=np.int64)
    for i in range(len(P)):
        if join[i] == 0:
            continue
        blocked = 0
        for t in range(nptr[i], nptr[i + 1]):
            j = nbr[t]
            m = mask[j] & ~blocked
            if m != 0:
                blocked |= _blocked(P, i, j, m, r2, full)
                if blocked == full:
                    break
        _join(i, blocked, full, mask, counts)
    return counts
