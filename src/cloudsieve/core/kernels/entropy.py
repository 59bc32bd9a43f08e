"""The entropy terms of the exact leave-one-out scores, from the k-NN distances.

For the scored points x of clusters 0..c-1 (definitions: :mod:`..entropy`):

- w = r_k^-d as exp(lw), lw = -d (log r_k - min_R log r_k): a cluster's largest weight is 1;
- W = sum_R w, A = sum_R w lw per cluster; g = w (lw - A/W);
- dw, dg: the changes of w and g when r_k(x) becomes r_(k+1)(x);
- acc_w(y), acc_g(y): sums of dw, dg over y's reverse neighbours; the gain is
  log1p(dW / W) - dG / (W + dW), dW = acc_w(y) - w(y), dG = acc_g(y) - g(y).

Bit for bit equal to the numpy formulation: logs and exps are numpy's (its SIMD
differs from libm in the last bit), sums run in index order as ``np.bincount``'s,
no ``fastmath``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...errors import InvalidParameterError

__all__ = ["entropy_gain", "entropy_weights", "reverse_sums", "grouped_gain", "scores_to_input", "graph_to_input"]


@njit(cache=True, nogil=True)
def _cluster_min(lr, cl, c):
    out = np.full(c, np.inf)
    for i in range(len(lr)):
        if lr[i] < out[cl[i]]:
            out[cl[i]] = lr[i]
    return out


@njit(cache=True, nogil=True)
def _log_weights(lr, lr1, cl, shift, dim):
    """lw = -dim (log r_k - shift), lw1 the same with r_(k+1)."""
    n = len(lr)
    lw = np.empty(n)
    lw1 = np.empty(n)
    nd = -dim
    for i in range(n):
        sh = shift[cl[i]]
        lw[i] = nd * (lr[i] - sh)
        lw1[i] = nd * (lr1[i] - sh)
    return lw, lw1


@njit(cache=True, nogil=True)
def _terms(w, w1, lw, lw1, cl, c):
    """W, A per cluster (index order), then per point g, W of its cluster, dw = w1 - w and dg = g1 - g."""
    n = len(w)
    W = np.zeros(c)
    A = np.zeros(c)
    for i in range(n):
        W[cl[i]] += w[i]
        A[cl[i]] += w[i] * lw[i]
    L = np.empty(c)
    for j in range(c):
        L[j] = A[j] / W[j] if W[j] != 0.0 else np.nan
    gw = np.empty(n)
    Wc = np.empty(n)
    dw = np.empty(n)
    dg = np.empty(n)
    for i in range(n):
        Li = L[cl[i]]
        g = w[i] * (lw[i] - Li)
        g1 = w1[i] * (lw1[i] - Li)
        gw[i] = g
        Wc[i] = W[cl[i]]
        dw[i] = w1[i] - w[i]  # exactly 0.0 when r_(k+1) = r_k (ties)
        dg[i] = g1 - g
    return gw, Wc, dw, dg


@njit(cache=True, nogil=True)
def _reverse_sums(nbr, kr, dw, dg, tcl, cl, n):
    acc_w = np.zeros(n)
    acc_g = np.zeros(n)
    check = len(tcl) > 0
    for x in range(len(nbr)):
        a = dw[x]
        b = dg[x]
        for j in range(kr[x]):
            y = nbr[x, j]
            if y < 0 or y >= n:
                continue
            if check and tcl[y] != cl[x]:
                continue
            acc_w[y] += a
            acc_g[y] += b
    return acc_w, acc_g


@njit(cache=True, nogil=True)
def _grouped_log_weights(lr, lr1, indptr, kcl, scored, dim, lw, lw1):
    """lw, lw1 of :func:`_log_weights` per cluster (shift: the cluster's min of log r_k)."""
    nd = -dim
    for c in range(len(kcl)):
        if kcl[c] <= 0:
            continue
        sh = np.inf
        for p in range(indptr[c], indptr[c + 1]):
            if scored[p] and lr[p] < sh:
                sh = lr[p]
        for p in range(indptr[c], indptr[c + 1]):
            if scored[p]:
                lw[p] = nd * (lr[p] - sh)
                lw1[p] = nd * (lr1[p] - sh)


@njit(cache=True, nogil=True)
def _grouped_terms(w, w1, lw, lw1, indptr, kcl, koff, scored, nb, dW, dG, Wc):
    """Per cluster: W, A, the terms of :func:`_terms` and the in-cluster reverse sums; then dW, dG and W per scored point."""
    mmax = 1
    for c in range(len(kcl)):
        mmax = max(mmax, indptr[c + 1] - indptr[c])
    acc_w = np.empty(mmax)
    acc_g = np.empty(mmax)
    for c in range(len(kcl)):
        k = kcl[c]
        if k <= 0:
            continue
        s = indptr[c]
        e = indptr[c + 1]
        W = 0.0
        A = 0.0
        for p in range(s, e):
            if scored[p]:
                W += w[p]
                A += w[p] * lw[p]
        L = A / W if W != 0.0 else np.nan
        for t in range(e - s):
            acc_w[t] = 0.0
            acc_g[t] = 0.0
        for p in range(s, e):
            if not scored[p]:
                continue
            g = w[p] * (lw[p] - L)
            g1 = w1[p] * (lw1[p] - L)
            a = w1[p] - w[p]
            b = g1 - g
            o = koff[c] + (p - s) * k
            for j in range(k):
                y = nb[o + j]
                if s <= y < e:
                    acc_w[y - s] += a
                    acc_g[y - s] += b
        for p in range(s, e):
            if scored[p]:
                dW[p] = acc_w[p - s] - w[p]
                dG[p] = acc_g[p - s] - w[p] * (lw[p] - L)
                Wc[p] = W


def grouped_gain(rk, rk1, indptr, kcl, koff, scored, nb, dim):
    """H(R - y) - H(R) of every scored point, in the layout of :mod:`cloudsieve.core.scored_knn`.

    ``rk``, ``rk1`` > 0 where scored; ``nb`` entries outside the cluster (e.g. n for
    context) are skipped. Returns float64 (n,): the gain at scored positions (0.0
    elsewhere), bit for bit :func:`entropy_gain`'s.
    """
    n = len(rk)
    lr = np.log(rk)  # numpy's log and exp (see the module docstring)
    lr1 = np.log(rk1)
    lw = np.zeros(n)
    lw1 = np.zeros(n)
    _grouped_log_weights(lr, lr1, indptr, kcl, scored, float(dim), lw, lw1)
    del lr, lr1
    w = np.exp(lw)
    w1 = np.exp(lw1)
    dW = np.zeros(n)
    dG = np.zeros(n)
    Wc = np.ones(n)
    _grouped_terms(w, w1, lw, lw1, indptr, kcl, koff, scored, nb, dW, dG, Wc)
    del w, w1, lw, lw1
    # log1p(dW / W) - dG / (W + dW), as entropy_change, in place
    gain = np.divide(dW, Wc)
    np.log1p(gain, out=gain)
    np.add(Wc, dW, out=Wc)
    np.divide(dG, Wc, out=dG)
    np.subtract(gain, dG, out=gain)
    return gain


@njit(cache=True, nogil=True)
def _to_input(order, indptr, kcl, scored, dup, msize, gain, dh, sg, unit, m_in, k_in, dup_in):
    for c in range(len(kcl)):
        m = msize[c]
        fm = np.float64(m)
        for p in range(indptr[c], indptr[c + 1]):
            i = order[p]
            if scored[p]:
                v = gain[p]
                a = abs(v)
                k_in[i] = kcl[c]
            elif dup[p]:
                v = 0.0
                a = 0.0
                k_in[i] = 0
            else:
                v = np.inf
                a = np.inf
                k_in[i] = 0
            dh[i] = a
            sg[i] = v
            unit[i] = 0.0 if dup[p] else a * fm
            m_in[i] = m
            dup_in[i] = dup[p]


def scores_to_input(order, indptr, kcl, scored, dup, msize, gain):
    """The fields of a Scores record in input order, from the grouped values.

    Returns dh, unit (m dH), sg (gain; +inf unscored), m, k (0 unscored) and dup, each (n,); copies get 0.
    """
    n = len(order)
    dh = np.empty(n)
    sg = np.empty(n)
    unit = np.empty(n)
    m_in = np.empty(n, dtype=np.int64)
    k_in = np.empty(n, dtype=np.int64)
    dup_in = np.empty(n, dtype=bool)
    _to_input(order, indptr, kcl, scored, dup, msize, gain, dh, sg, unit, m_in, k_in, dup_in)
    return dh, unit, sg, m_in, k_in, dup_in


@njit(cache=True, nogil=True)
def _graph(order, indptr, kcl, koff, scored, nb, out):
    n = len(order)
    for c in range(len(kcl)):
        k = kcl[c]
        s = indptr[c]
        for p in range(s, indptr[c + 1]):
            if scored[p]:
                i = order[p]
                o = koff[c] + (p - s) * k
                for j in range(k):
                    y = nb[o + j]
                    out[i, j] = order[y] if 0 <= y < n else -1


def graph_to_input(order, indptr, kcl, koff, scored, nb, width):
    """The k-NN graph in input order: (n, width) int64, nearest first, -1 padded and for unscored rows."""
    out = np.full((len(order), int(width)), -1, dtype=np.int64)
    _graph(order, indptr, kcl, koff, scored, nb, out)
    return out


def entropy_weights(cl, c, rk, rk1, dim):
    """w, g, W of the cluster, dw and dg for every scored point (M,).

    ``cl`` (M,) cluster in 0..c-1; ``rk``, ``rk1`` (M,) > 0; ``dim`` the exponent d.
    Returns w, gw, Wc, dw, dg, each float64 (M,).
    """
    cl = np.ascontiguousarray(cl, dtype=np.int64)
    lr = np.log(rk)  # numpy's log and exp, as the numpy code (not numba's libm)
    lr1 = np.log(rk1)
    shift = _cluster_min(lr, cl, int(c))
    lw, lw1 = _log_weights(lr, lr1, cl, shift, float(dim))
    w = np.exp(lw)
    w1 = np.exp(lw1)
    gw, Wc, dw, dg = _terms(w, w1, lw, lw1, cl, int(c))
    return w, gw, Wc, dw, dg


def reverse_sums(nbr, kr, dw, dg, n, target_cluster=None, cl=None):
    """Sums acc_w, acc_g (n,) float64 of dw and dg (M,) over each point's reverse neighbours.

    ``nbr`` (M, K): neighbours of scored point x, nearest first (positions in 0..n-1;
    others skipped), of which the first kr[x] count. With ``target_cluster`` (n,) and
    ``cl`` (M,), x counts for y only if target_cluster[y] == cl[x]. Added in row order,
    as ``np.bincount``.
    """
    if target_cluster is None:
        tcl = np.zeros(0, dtype=np.int64)
        cl = np.zeros(len(dw), dtype=np.int64)
    else:
        tcl = np.ascontiguousarray(target_cluster, dtype=np.int64)
        cl = np.ascontiguousarray(cl, dtype=np.int64)
    nbr = np.asarray(nbr)
    if nbr.ndim != 2 or len(nbr) != len(dw) or len(kr) != len(dw) or (len(kr) and int(np.max(kr)) > nbr.shape[1]):
        raise InvalidParameterError(
            f"nbr must have shape (M, K) with M = {len(dw)} rows and K >= max(kr), got shape {nbr.shape}")
    return _reverse_sums(nbr, np.ascontiguousarray(kr, dtype=np.int64), dw, dg, tcl, cl, int(n))


def entropy_gain(rows, cl, c, rk, rk1, nbr, kr, dim, n, target_cluster=None):
    """Signed gain H(R - y) - H(R) for every scored point y (M,), float64.

    ``rows``: position of each scored point in 0..n-1; ``cl, c, rk, rk1, dim`` as
    :func:`entropy_weights`; ``nbr, kr, n, target_cluster`` as :func:`reverse_sums`.
    Bit for bit what ``entropy.score_points`` computes.
    """
    w, gw, Wc, dw, dg = entropy_weights(cl, c, rk, rk1, dim)
    acc_w, acc_g = reverse_sums(nbr, kr, dw, dg, n, target_cluster, cl if target_cluster is not None else None)
    dW = acc_w[rows] - w
    dG = acc_g[rows] - gw
    return np.log1p(dW / Wc) - dG / (Wc + dW)
