"""Compiled kernels of the elimination's neighbour lists (numba; private, inputs assumed valid).

The neighbours of a point within 2 r_max are listed once, in parallel, as a
CSR (``nptr`` (n + 1,), ``nbr`` the neighbour rows) in the order of the grid
walk of :mod:`.grid` (cells in ``ncells`` order, rows ascending inside a
cell), with ``low`` (float32) a lower bound of each one's crowding term
(1 - d / (2 r_max)) ** alpha (enough for the upper bounds of the keys the
elimination keeps) and ``soff`` each list's positions sorted nearest first
(by squared distance, then tie; uint8/uint16 when the lists are short), and
``term`` each one's exact crowding term (float64). A point's list holds
every other alive point (``state`` != 0) at squared distance < (2 r_max)^2,
so the exact crowding sum over the list in list order
(:func:`term_weight`: the stored terms, no square roots, no neighbour
coordinates read) is the one over the grid walk, bit for bit.
Grid arguments as in :mod:`.grid"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from .grid import nearest

SHRINK = 1.0 - 2.0**-23  # a float64 times this, rounded to float32, is below it
TINY = 1e-30  # terms below it are bounded by 0


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


@njit(cache=True)
def term_weight(i, nptr, nbr, state, term):
    """Crowding sum of point i over its alive neighbours from the stored terms (the grid walk's sum, bit
    for bit: the same terms in the same order)."""
    w = 0.0
    for t in range(nptr[i], nptr[i + 1]):
        if state[nbr[t]] != 0:
            w += term[t]
    return w


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
def fill_lists(P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, nptr, nbr, low, w, term):
    """Fill ``nbr``/``low`` (nptr[-1],) of the lists counted by :func:`count_lists`, in grid walk order,
    and ``w`` (n,) with each alive point's exact crowding sum (:func:`term_weight`'s, bit for bit), and ``term``."""
    n = len(P)
    r2 = two_r * two_r
    inv2r = 1.0 / two_r
    for i in prange(n):
        if state[i] == 0:
            continue
        c = cell[i]
        k = nptr[i]
        s = 0.0
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
                    u = ipow(1.0 - math.sqrt(d2) * inv2r, alpha, ialpha)
                    s += u
                    term[k] = u
                    nbr[k] = j
                    low[k] = np.float32(u * SHRINK) if u > TINY else np.float32(0.0)
                    k += 1
        w[i] = s


@njit(cache=True)
def _ties_by_tie(o, d2, nbr, s, tie):
    """In the positions o sorted by d2, order each run of equal distances by tie (insertion sort; runs are
    short)."""
    k = len(o)
    a = 0
    while a < k:
        b = a + 1
        while b < k and d2[o[b]] == d2[o[a]]:
            b += 1
        for u in range(a + 1, b):
            v = o[u]
            q = u - 1
            while q >= a and tie[nbr[s + o[q]]] > tie[nbr[s + v]]:
                o[q + 1] = o[q]
                q -= 1
            o[q + 1] = v
        a = b


@njit(cache=True, parallel=True)
def sort_lists(P, nptr, nbr, tie, soff):
    """Fill ``soff`` (nptr[-1],) with each list's positions sorted by (squared distance, tie): nearest first."""
    n = len(nptr) - 1
    for p in prange(n):
        s, e = nptr[p], nptr[p + 1]
        k = e - s
        if k == 0:
            continue
        d2 = np.empty(k)
        for t in range(k):
            j = nbr[s + t]
            dx = P[j, 0] - P[p, 0]
            dy = P[j, 1] - P[p, 1]
            dz = P[j, 2] - P[p, 2]
            d2[t] = dx * dx + dy * dy + dz * dz
        o = np.argsort(d2, kind="mergesort")
        _ties_by_tie(o, d2, nbr, s, tie)
        for t in range(k):
            soff[s + t] = o[t]


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


@njit(cache=True)
def lists_one_pass(P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, tie, nearest_first, start, k, nptr,
                   nbr, low, term, soff, dd, w):
    """:func:`count_lists` + :func:`fill_lists` + :func:`sort_lists` in one sequential pass (one thread):
    each distance computed once, each list sorted while its entries are at hand (insertion sort by
    (squared distance, tie): the lists are short, 6 entries on average at 50% kept; longer than 32 as
    :func:`sort_lists` does). The same arrays bit for bit. Fills rows from ``start``, entries from ``k``,
    into buffers of one capacity (``dd`` the entries' squared distances, scratch; ``soff`` uint16) until a
    row does not fit; returns (the first row not filled, its first entry). The caller grows the buffers
    and goes on: growing them here makes every store slower."""
    n = len(P)
    cap = len(nbr)
    r2 = two_r * two_r
    inv2r = 1.0 / two_r
    for i in range(start, n):
        nptr[i] = k
        if state[i] == 0:
            continue
        c = cell[i]
        s = 0.0
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
                    if k == cap:
                        return i, nptr[i]
                    u = ipow(1.0 - math.sqrt(d2) * inv2r, alpha, ialpha)
                    s += u
                    term[k] = u
                    nbr[k] = j
                    low[k] = np.float32(u * SHRINK) if u > TINY else np.float32(0.0)
                    dd[k] = d2
                    k += 1
        w[i] = s
        b = nptr[i]
        m = k - b
        if not nearest_first or m == 0:
            continue
        if m > 32:  # long lists (dense spots): sort_lists' way
            o = np.argsort(dd[b:k], kind="mergesort")
            _ties_by_tie(o, dd[b:k], nbr, b, tie)
            for t in range(m):
                soff[b + t] = o[t]
            continue
        for t in range(m):  # insertion sort of the positions by (squared distance, tie), in soff[b:k]
            q = t - 1
            while q >= 0 and (dd[b + soff[b + q]] > dd[b + t] or (dd[b + soff[b + q]] == dd[b + t]
                                                                  and tie[nbr[b + soff[b + q]]] > tie[nbr[b + t]])):
                soff[b + q + 1] = soff[b + q]
                q -= 1
            soff[b + q + 1] = t
    nptr[n] = k
    return n, k


def index_type(*sizes) -> type:
    """int32 when every index fits, else int64."""
    return np.int32 if max(int(s) for s in sizes) < 2**31 else np.int64


def build_lists(P, cell, cstart, nstart, ncells, order, state, two_r, alpha, ialpha, nearest_first):
    """Neighbour lists within ``two_r`` of every alive row: nptr (n + 1,), nbr, low, soff (positions
    nearest first, if ``nearest_first``: the coverage term's searches need them; else one 0) and the
    exact crowding sums w (n,) and terms (nptr[-1],). ``order``: the grid's rows' ids (the tie of equal distances)."""
    if numba.get_num_threads() == 1:  # one pass (the engine's cells run one thread each)
        n = len(P)
        nptr = np.zeros(n + 1, dtype=np.int64)
        w = np.zeros(n)
        cap = 8 * n + 64  # 6 entries a point at 50% kept; more at lower ratios: grown below
        nbr = np.empty(cap, dtype=index_type(n))
        low = np.empty(cap, dtype=np.float32)
        term = np.empty(cap)
        soff = np.empty(cap if nearest_first else 1, dtype=np.uint16)
        dd = np.empty(cap)
        row, k = 0, 0
        while True:
            row, k = lists_one_pass(P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, order,
                                    nearest_first, row, k, nptr, nbr, low, term, soff, dd, w)
            if row == n:
                break
            cap *= 2
            nbr, low, term, dd = (np.resize(a, cap) for a in (nbr, low, term, dd))
            if nearest_first:
                soff = np.resize(soff, cap)
        longest = int(np.diff(nptr).max(initial=0))
        if longest <= 65536:
            kind = np.uint8 if longest <= 256 else np.uint16
            soff = soff[:k].astype(kind) if nearest_first else np.zeros(1, dtype=kind)
            return nptr, nbr[:k].copy(), low[:k].copy(), soff, w, term[:k].copy()
    return three_pass_lists(P, cell, cstart, nstart, ncells, order, state, two_r, alpha, ialpha, nearest_first)


def three_pass_lists(P, cell, cstart, nstart, ncells, order, state, two_r, alpha, ialpha, nearest_first):
    """:func:`build_lists` in three parallel passes (count, fill, sort), with several threads."""
    counts = count_lists(P, cell, cstart, nstart, ncells, state, two_r)
    nptr = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=nptr[1:])
    nbr = np.empty(int(nptr[-1]), dtype=index_type(len(counts)))
    low = np.empty(int(nptr[-1]), dtype=np.float32)
    w = np.zeros(len(counts))
    term = np.empty(int(nptr[-1]))
    fill_lists(P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, nptr, nbr, low, w, term)
    longest = int(counts.max(initial=0))
    soff = np.zeros(int(nptr[-1]) if nearest_first else 1,
                    dtype=np.uint8 if longest <= 256 else np.uint16 if longest <= 65536 else np.int64)
    if nearest_first:
        sort_lists(P, nptr, nbr, order, soff)
    return nptr, nbr, low, soff, w, term
