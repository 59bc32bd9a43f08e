"""Compiled kernels of the elimination's neighbour lists (numba; private, inputs assumed valid).

:func:`build_lists` lists each point's alive neighbours within 2 r_max once, as a
CSR (``nptr`` (n + 1,), ``nbr``) in the grid walk's order (:mod:`.grid`), with
``low`` (float32) a lower bound of each crowding term, ``term`` the exact term
(float64), and ``soff`` each list's positions nearest first (by squared distance,
then tie). The crowding sum over a list in list order (:func:`term_weight`) equals
the grid walk's, bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit

from .grid import nearest
from .order import stable_sort
from .threads import Chunks

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
    """Crowding sum of point i over its alive neighbours from the stored terms (the grid walk's sum, bit for bit)."""
    w = 0.0
    for t in range(nptr[i], nptr[i + 1]):
        if state[nbr[t]] != 0:
            w += term[t]
    return w


@njit(cache=True, _nrt=False)
def _ties_by_tie(soff, b, k, dd, nbr, tie):
    """Order each run of equal distances in soff[b:k] (sorted by distance ``dd``) by tie (insertion sort)."""
    a = b
    while a < k:
        e = a + 1
        while e < k and dd[soff[e]] == dd[soff[a]]:
            e += 1
        for u in range(a + 1, e):
            v = soff[u]
            q = u - 1
            while q >= a and tie[nbr[b + soff[q]]] > tie[nbr[b + v]]:
                soff[q + 1] = soff[q]
                q -= 1
            soff[q + 1] = v
        a = e


@njit(cache=True)
def list_nearest(p, x, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr):
    """:func:`.grid.nearest` from p's list (p's initial list); the grid walk only when no alive point of it is within 2 r_max."""
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


@njit(cache=True, nogil=True)
def lists_one_pass(P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, tie, nearest_first, lo, start, stop,
                   k, nptr, nbr, low, term, soff, dd, w):
    """The lists of rows [start, stop) in one pass, each sorted by (squared distance, tie) while at hand.

    Row r's list starts at ``nptr[r - lo]`` of the buffers from entry ``k`` (``dd``:
    scratch for one row's candidates); ``w[r]`` its crowding sum. Returns (row, entry)
    of the first row that does not fit; the caller grows the buffers and goes on.
    """
    cap = len(nbr)
    r2 = two_r * two_r
    inv2r = 1.0 / two_r
    buf = np.empty(64, dtype=soff.dtype)
    kbuf = np.empty(64)
    kbuf2 = np.empty(64)
    for i in range(start, stop):
        nptr[i - lo] = k
        if state[i] == 0:
            continue
        c = cell[i]
        b = k
        x0, y0, z0 = P[i, 0], P[i, 1], P[i, 2]
        for t in range(nstart[c], nstart[c + 1]):
            cc = ncells[t]
            for j in range(cstart[cc], cstart[cc + 1]):
                if k == cap:
                    return i, nptr[i - lo]
                dx = P[j, 0] - x0
                dy = P[j, 1] - y0
                dz = P[j, 2] - z0
                d2 = dx * dx + dy * dy + dz * dz
                # every candidate written, kept by moving on (branch-free)
                nbr[k] = j
                dd[k - b] = d2
                k += (d2 < r2) & (j != i) & (state[j] != 0)
        s = 0.0
        for t in range(b, k):  # the terms in the walk's order: the same sum
            u = ipow(1.0 - math.sqrt(dd[t - b]) * inv2r, alpha, ialpha)
            s += u
            term[t] = u
            low[t] = np.float32(u * SHRINK) if u > TINY else np.float32(0.0)
        w[i] = s
        m = k - b
        if not nearest_first or m == 0:
            continue
        if m > 32:  # long lists (low ratios, dense spots): a merge sort of a copy of the distances with the
            # positions along, then ties by tie (numpy's argsort made an array a row)
            if len(buf) < m:
                buf = np.empty(2 * m, dtype=soff.dtype)
                kbuf = np.empty(2 * m)
                kbuf2 = np.empty(2 * m)
            for t in range(m):
                soff[b + t] = t
                kbuf[t] = dd[t]
            stable_sort(kbuf, soff[b:k], m, kbuf2, buf)
            _ties_by_tie(soff, b, k, dd, nbr, tie)
            continue
        if m <= 16:  # each position's rank by counting: no branch on the comparisons (an insertion sort
            # mispredicted about one a shift); (squared distance, tie) are distinct, so the ranks are too
            for t in range(m):
                kbuf[t] = dd[t]
                kbuf2[t] = tie[nbr[b + t]]  # the ids as float64: exact below 2^53
            for t in range(m):
                v = kbuf[t]
                tv = kbuf2[t]
                rank = 0
                for u in range(m):
                    rank += (kbuf[u] < v) | ((kbuf[u] == v) & (kbuf2[u] < tv))
                soff[b + rank] = t
            continue
        for t in range(m):  # insertion sort of the positions by (squared distance, tie), in soff[b:k]; the
            # sorted distances beside them in kbuf (one load a comparison instead of two dependent ones)
            v = dd[t]
            q = t - 1
            while q >= 0 and (kbuf[q] > v or (kbuf[q] == v and tie[nbr[b + soff[b + q]]] > tie[nbr[b + t]])):
                kbuf[q + 1] = kbuf[q]
                soff[b + q + 1] = soff[b + q]
                q -= 1
            kbuf[q + 1] = v
            soff[b + q + 1] = t
    nptr[stop - lo] = k
    return stop, k


def _grown(a: np.ndarray, cap: int, k: int) -> np.ndarray:
    """A buffer of *cap* entries holding the first *k* of *a*."""
    out = np.empty(cap, dtype=a.dtype)
    out[:k] = a[:k]
    return out


def _rows_lists(args, w, lo, hi, kind, nearest_first, reach):
    """The lists of rows [lo, hi) by :func:`lists_one_pass`, buffers grown until they fit.

    *reach*: each cell's candidates. Returns local nptr (hi - lo + 1,), nbr, low, term, soff (int32), the longest list.
    """
    cap = 8 * (hi - lo) + 64  # 6 entries a point at 50% kept; more at lower ratios: grown below
    nptr = np.zeros(hi - lo + 1, dtype=np.int64)
    nbr = np.empty(cap, dtype=kind)
    low = np.empty(cap, dtype=np.float32)
    term = np.empty(cap)
    soff = np.empty(cap if nearest_first else 1, dtype=np.int32)
    dd = np.empty(int(reach.max(initial=0)))
    row, k = lo, 0
    cand = None
    while True:
        row, k = lists_one_pass(*args, nearest_first, lo, row, hi, k, nptr, nbr, low, term, soff, dd, w)
        if row == hi:
            break
        if cand is None:  # the candidates of the rows so far, cumulated (alive rows only: the others list none)
            cell, state = args[1], args[5]
            cand = np.cumsum(reach[cell[lo:hi]] * (state[lo:hi] != 0))
        # grown to the share of candidates listed so far over all rows' candidates, a tenth to spare
        done = int(cand[row - lo - 1]) if row > lo else 0
        need = int(1.1 * k / max(done, 1) * int(cand[-1])) + 64
        cap = max(need, k + int(reach.max(initial=0)) + 64)
        nbr, low, term = (_grown(a, cap, k) for a in (nbr, low, term))
        if nearest_first:
            soff = _grown(soff, cap, k)
    for a in (nbr, low, term, soff) if nearest_first else (nbr, low, term):
        a.resize(k, refcheck=False)  # the spare entries given back in place (no copy: the lists are held while
        # their cell is eliminated)
    return nptr, nbr, low, term, soff[: k if nearest_first else 0], int(np.diff(nptr).max(initial=0))


def index_type(*sizes) -> type:
    """int32 when every index fits, else int64."""
    return np.int32 if max(int(s) for s in sizes) < 2**31 else np.int64


def build_lists(P, cell, cstart, nstart, ncells, order, state, two_r, alpha, ialpha, nearest_first, rows=16384):
    """Neighbour lists within ``two_r`` of every alive row: nptr (n + 1,), nbr, low, soff, sums w (n,), terms (nptr[-1],).

    ``soff`` only with ``nearest_first`` (else one 0); ``order``: row ids (ties).
    Ranges of >= ``rows`` rows run on threads (:class:`.threads.Chunks`); the result does not depend on them.
    """
    n = len(P)
    kind = index_type(n)
    w = np.zeros(n)
    args = (P, cell, cstart, nstart, ncells, state, two_r, alpha, ialpha, order)
    around = np.r_[0, np.cumsum(np.diff(cstart)[ncells])]
    reach = around[nstart[1:]] - around[nstart[:-1]]  # the points in the cells around each cell
    with Chunks(numba.get_num_threads()) as chunks:
        parts = chunks.map(lambda a, b: _rows_lists(args, w, a, b, kind, nearest_first, reach), n, min_chunk=rows)
    longest = max(p[5] for p in parts)
    if len(parts) == 1:  # one range (one thread): its arrays as they are, no copy
        nptr, nbr, low, term = parts[0][:4]
    else:
        sizes = np.array([len(p[1]) for p in parts], dtype=np.int64)
        base = np.r_[0, np.cumsum(sizes)]
        nptr = np.concatenate([p[0][:-1] + base[i] for i, p in enumerate(parts)] + [base[-1:]])
        nbr, low, term = (np.concatenate([p[j] for p in parts]) for j in (1, 2, 3))
    dtype = np.uint8 if longest <= 256 else np.uint16 if longest <= 65536 else np.int64
    if not nearest_first:
        return nptr, nbr, low, np.zeros(1, dtype=dtype), w, term
    return nptr, nbr, low, np.concatenate([p[4] for p in parts]).astype(dtype), w, term
