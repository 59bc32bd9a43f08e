"""Compiled kernels of the elimination's neighbour lists (numba; private, inputs assumed valid).

The neighbours of a point within 2 r_max are listed once, in parallel, as a
CSR (``nptr`` (n + 1,), ``nbr`` the neighbour rows, ``term`` their crowding
terms), so the sequential elimination loop never walks the grid again. A
point's list holds every other alive point (``state`` != 0) at squared
distance < (2 r_max)^2 in the order of the grid walk of :mod:`.grid` (cells
in ``ncells`` order, rows ascending inside a cell): a sum over the list in
list order is the sum the grid walk made, bit for bit. Grid arguments as in
:mod:`.grid`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .grid import nearest


@njit(cache=True)
def ipow(u, alpha, ialpha):
    """u ** alpha; by repeated squaring when alpha is a small integer (ialpha >= 0)."""
    if ialpha < 0:
        return u**alpha
    r = 1.0
    e = ialpha
    while e > 0:
        if e & 1:
            r *= u
        u *= u
        e >>= 1
    return r


@njit(cache=True, parallel=True)
def count_lists(P, cell, cstart, nstart, ncells, state, two_r):
    """Length (n,) int64 of each alive point's list (0 for absent points)."""
    n = len(P)
    r2 = two_r * two_r
    out = np.zeros(n, dtype=np.int64)
    for i in prange(n):
        if state[i] == 0:
            continue
        c = cell[i]
        k = 0
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            for j in range(cstart[cc], cstart[cc + 1]):
                if j == i or state[j] == 0:
                    continue
                dx = P[j, 0] - P[i, 0]
                dy = P[j, 1] - P[i, 1]
                dz = P[j, 2] - P[i, 2]
                if dx * dx + dy * dy + dz * dz < r2:
                    k += 1
        out[i] = k
    return out


@njit(cache=True, parallel=True)
def fill_lists(P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, nptr, nbr, term):
    """Fill ``nbr``/``term`` (nptr[-1],) of the lists counted by :func:`count_lists`:
    term = (1 - d / (2 r_max)) ** alpha, computed as the grid walk did."""
    n = len(P)
    r2 = two_r * two_r
    inv2r = 1.0 / two_r
    for i in prange(n):
        if state[i] == 0:
            continue
        c = cell[i]
        k = nptr[i]
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            for j in range(cstart[cc], cstart[cc + 1]):
                if j == i or state[j] == 0:
                    continue
                dx = P[j, 0] - P[i, 0]
                dy = P[j, 1] - P[i, 1]
                dz = P[j, 2] - P[i, 2]
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < r2:
                    nbr[k] = j
                    term[k] = ipow(1.0 - math.sqrt(d2) * inv2r, alpha, ialpha)
                    k += 1


@njit(cache=True)
def list_weight(i, nptr, nbr, term, state):
    """Crowding sum of point i over its alive neighbours (the grid walk's sum, bit for bit)."""
    w = 0.0
    for t in range(nptr[i], nptr[i + 1]):
        if state[nbr[t]] != 0:
            w += term[t]
    return w


@njit(cache=True, parallel=True)
def list_weights(nptr, nbr, term, state):
    """Crowding sum w (n,) of every removable point (state 1; 0.0 for the others)."""
    n = len(state)
    out = np.zeros(n)
    for i in prange(n):
        if state[i] == 1:
            out[i] = list_weight(i, nptr, nbr, term, state)
    return out


@njit(cache=True)
def list_nearest(p, x, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr):
    """:func:`.grid.nearest` (the nearest alive point to p other than x, equal distances lower ``tie``;
    squared distance) from p's list; the grid walk only when no alive point of it is within 2 r_max.
    p's list must be the one of its initial state (p alive then)."""
    best = -1
    bd = np.inf
    for t in range(nptr[p], nptr[p + 1]):
        j = nbr[t]
        if j == x or state[j] == 0:
            continue
        dx = P[j, 0] - P[p, 0]
        dy = P[j, 1] - P[p, 1]
        dz = P[j, 2] - P[p, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < bd or (d2 == bd and tie[j] < tie[best]):
            bd = d2
            best = j
    if best < 0:
        return nearest(p, x, P, cell, cstart, nstart, ncells, state, tie)
    return best, bd


@njit(cache=True, parallel=True)
def sort_lists(P, nptr, nbr, tie):
    """Each list's rows sorted by (squared distance, tie): the nearest first (same dtype as ``nbr``)."""
    n = len(nptr) - 1
    out = np.empty_like(nbr)
    for p in prange(n):
        s, e = nptr[p], nptr[p + 1]
        if e == s:
            continue
        d2 = np.empty(e - s)
        for t in range(s, e):
            j = nbr[t]
            dx = P[j, 0] - P[p, 0]
            dy = P[j, 1] - P[p, 1]
            dz = P[j, 2] - P[p, 2]
            d2[t - s] = dx * dx + dy * dy + dz * dz
        o = np.argsort(d2, kind="mergesort")
        a = 0
        while a < e - s:  # runs of equal distances: by tie (insertion sort; runs are short)
            b = a + 1
            while b < e - s and d2[o[b]] == d2[o[a]]:
                b += 1
            for u in range(a + 1, b):
                v = o[u]
                k = u - 1
                while k >= a and tie[nbr[s + o[k]]] > tie[nbr[s + v]]:
                    o[k + 1] = o[k]
                    k -= 1
                o[k + 1] = v
            a = b
        for t in range(e - s):
            out[s + t] = nbr[s + o[t]]
    return out
