"""The incremental rescoring kernels (core/kernels/rescore.py): the terms of entropy_weights, bit for bit."""

from __future__ import annotations

import numpy as np

from cloudsieve.core.entropy import entropy_change
from cloudsieve.core.kernels.entropy import entropy_weights
from cloudsieve.core.kernels import rescore as ks


def test_rescore_kernels_are_entropy_weights():
    rng = np.random.default_rng(9)
    sizes = rng.integers(20, 300, 15)
    starts = np.r_[0, np.cumsum(sizes)]
    n = int(starts[-1])
    c = len(sizes)
    ginv = np.repeat(np.arange(c), sizes)
    k = np.maximum(4, np.floor(np.sqrt(sizes) + 0.5).astype(np.int64))
    kk = k[ginv].copy()
    kk[rng.random(n) < 0.05] = 0  # rows without a list (copies, removed points)
    W = int(k.max()) + 5
    nb = (starts[ginv][:, None] + rng.integers(0, 1 << 30, (n, W)) % sizes[ginv][:, None]).astype(np.int32)
    rk = rng.random(n) * 3 + 0.01
    rk1 = rk * (1 + (rng.random(n) < 0.7) * rng.random(n))  # r_(k+1) = r_k for some (ties)
    touched = rng.random(c) < 0.8
    rows = ks.scored_rows(touched, ginv, kk, 0, n)
    np.testing.assert_array_equal(rows, np.flatnonzero(touched[ginv] & (kk > 0)))
    # the reference: entropy_weights and bincount scatters, as the numpy rounds computed them
    cl = ginv[rows]
    w, gw, Wc, dw, dg = entropy_weights(cl, c, rk[rows], rk1[rows], 3)
    acc_w = np.zeros(n)
    acc_g = np.zeros(n)
    for kv in np.unique(kk[rows]):
        at = np.flatnonzero(kk[rows] == kv)
        tgt = nb[rows[at], :kv].ravel()
        acc_w += np.bincount(tgt, weights=np.repeat(dw[at], kv), minlength=n)
        acc_g += np.bincount(tgt, weights=np.repeat(dg[at], kv), minlength=n)
    with np.errstate(invalid="ignore"):  # random lists: some changes exceed W (NaN on both sides)
        want = entropy_change(acc_w[rows] - w, acc_g[rows] - gw, Wc)
    # the kernels, on two cluster ranges
    out = np.empty(len(rows))
    sw, sg = np.zeros(n), np.zeros(n)
    for c0, c1 in [(0, 6), (6, c)]:
        sel = (cl >= c0) & (cl < c1)
        r = rows[sel]
        lw, lw1 = ks.log_weights(r, ginv, c0, c1, np.log(rk[r]), np.log(rk1[r]), -3.0)
        dW, dG, Wr = ks.entropy_deltas(r, ginv, c0, c1, kk, nb, np.exp(lw), np.exp(lw1), lw, lw1, sw, sg)
        np.testing.assert_array_equal(Wr, Wc[sel])
        with np.errstate(invalid="ignore"):
            out[sel] = entropy_change(dW, dG, Wr)
    np.testing.assert_array_equal(out, want)  # bit for bit
    val = np.full(n, np.nan)
    m = np.bincount(ginv, minlength=c)
    ks.store_scores(rows, ginv, np.abs(out), m, True, val)
    np.testing.assert_array_equal(val[rows], np.abs(want) * m[cl])
