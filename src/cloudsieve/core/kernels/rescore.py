"""Compiled kernels of the incremental rescoring between rounds (numba; private, inputs assumed valid).

Scores of the clusters that lost a row, from the kept lists (:mod:`.lists`), with
the terms of :func:`.entropy.entropy_weights` operation for operation (gain:
:func:`cloudsieve.core.entropy.entropy_change`); the caller takes ``log`` and
``exp`` from numpy. Kernels take a cluster range (c0, c1) for threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def scored_rows(touched, ginv, kk, a, b):
    """The rows a to b - 1 with a list (kk > 0) in the ``touched`` clusters, ascending (int64)."""
    rows = np.empty(b - a, dtype=np.int64)
    m = 0
    for i in range(a, b):
        if kk[i] > 0 and touched[ginv[i]]:
            rows[m] = i
            m += 1
    return rows[:m].copy()


@njit(cache=True, nogil=True)
def log_weights(rows, ginv, c0, c1, lr, lr1, neg_dim):
    """lw, lw1 (M,): -d (log r - min over the cluster of log r_k) for r_k and r_(k+1), clusters c0 to c1 - 1.

    ``lr``, ``lr1``: log r_k, log r_(k+1); ``neg_dim`` = -d.
    """
    M = len(rows)
    shift = np.full(c1 - c0, np.inf)
    for i in range(M):
        cl = ginv[rows[i]] - c0
        if lr[i] < shift[cl]:
            shift[cl] = lr[i]
    lw = np.empty(M)
    lw1 = np.empty(M)
    for i in range(M):
        s = shift[ginv[rows[i]] - c0]
        lw[i] = neg_dim * (lr[i] - s)
        lw1[i] = neg_dim * (lr1[i] - s)
    return lw, lw1


@njit(cache=True, nogil=True)
def entropy_deltas(rows, ginv, c0, c1, kk, nb, w, w1, lw, lw1, acc_w, acc_g):
    """dW, dG, W (M,) float64: changes of W and G when each row leaves its cluster, and the cluster's W.

    Each row x passes (w' - w, g' - g) to its first kk[x] list entries; removing y
    changes W by what y received minus w(y) (same for g). ``acc_w``/``acc_g`` (n,): scratch.
    """
    M = len(rows)
    Wc = np.zeros(c1 - c0)
    Ac = np.zeros(c1 - c0)
    for i in range(M):
        cl = ginv[rows[i]] - c0
        Wc[cl] += w[i]
        Ac[cl] += w[i] * lw[i]
    gw = np.empty(M)
    dw = np.empty(M)
    dg = np.empty(M)
    for i in range(M):
        cl = ginv[rows[i]] - c0
        L = Ac[cl] / Wc[cl]
        g = w[i] * (lw[i] - L)
        g1 = w1[i] * (lw1[i] - L)
        gw[i] = g
        dw[i] = w1[i] - w[i]  # exactly 0 when r_(k+1) = r_k (ties)
        dg[i] = g1 - g
        acc_w[rows[i]] = 0.0
        acc_g[rows[i]] = 0.0
    for i in range(M):
        r = rows[i]
        for j in range(kk[r]):
            t = nb[r, j]
            acc_w[t] += dw[i]
            acc_g[t] += dg[i]
    dW = np.empty(M)
    dG = np.empty(M)
    W = np.empty(M)
    for i in range(M):
        r = rows[i]
        dW[i] = acc_w[r] - w[i]
        dG[i] = acc_g[r] - gw[i]
        W[i] = Wc[ginv[r] - c0]
    return dW, dG, W


@njit(cache=True, nogil=True)
def store_scores(rows, ginv, dh, m, use_unit, val):
    """val[rows] = dH, or m * dH (``m`` (c,) the clusters' distinct alive rows) with ``use_unit``."""
    for i in range(len(rows)):
        v = dh[i]
        if use_unit:
            v = v * m[ginv[rows[i]]]
        val[rows[i]] = v
