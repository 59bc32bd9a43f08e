"""One round's kernels (core/kernels/rounds.py): the coverage test and the greedy selection, against
their definitions."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.kernels import rounds as kr
from cloudsieve.core.rounds import _covered, _first_independent


def median_test(P, nb, kk, cand, coverage):
    """The coverage test by its definition: r_1(y) <= coverage * nanmedian of r_1 over y's listed neighbours."""
    n = len(P)
    valid = (nb >= 0) & (nb < n) & (np.arange(nb.shape[1]) < kk[:, None])
    has = (kk > 0) & valid[:, 0]
    r1 = np.full(n, np.inf)
    r1[has] = np.sqrt(((P[has] - P[nb[has, 0]]) ** 2).sum(axis=1))
    out = np.zeros(len(cand), dtype=bool)
    for i, y in enumerate(cand):
        if not has[y]:
            continue
        vals = r1[nb[y][valid[y]]]
        with np.errstate(invalid="ignore"):
            out[i] = len(vals) > 0 and r1[y] <= coverage * np.median(vals)
    return out


@pytest.mark.parametrize("coverage", [0.0, 0.5, 1.0, 1.7, np.inf])
def test_covered_is_the_median_test(coverage):
    rng = np.random.default_rng(6)
    n, K = 600, 9
    P = np.round(rng.random((n, 3)) * 4) / 4  # coarse grid: many equal spacings, medians between ties
    nb = rng.integers(0, n, (n, K))
    nb[rng.random((n, K)) < 0.1] = -1  # missing entries (context neighbours)
    loop = nb == np.arange(n)[:, None]
    nb[loop] = (nb[loop] + 1) % n  # no self loops
    kk = rng.integers(0, K + 1, n)  # odd and even counts, rows without a list
    cand = rng.permutation(n)[:400]
    np.testing.assert_array_equal(_covered(P, nb, cand, coverage, kk), median_test(P, nb, kk, cand, coverage))


def test_select_clusters_is_the_global_greedy_pass():
    rng = np.random.default_rng(7)
    sizes = rng.integers(5, 60, 30)
    starts = np.r_[0, np.cumsum(sizes)]
    n = int(starts[-1])
    K = 6
    cl = np.repeat(np.arange(len(sizes)), sizes)
    nb = (starts[cl][:, None] + rng.integers(0, 1 << 30, (n, K)) % sizes[cl][:, None]).astype(np.int32)
    nb[nb == np.arange(n)[:, None]] = n  # no self loops; n: no neighbour
    kk = rng.integers(0, K + 1, n)
    alive = rng.random(n) < 0.9
    val = np.round(rng.random(n) * 20) / 20  # many equal values: ties broken by ``tie``
    val[rng.random(n) < 0.1] = np.inf
    tie = rng.permutation(n)
    pool = np.flatnonzero(alive & np.isfinite(val))
    cand = pool[np.lexsort((tie[pool], val[pool]))]
    want = _first_independent(cand, nb.astype(np.int64), n, kk)
    got = kr.select_clusters(starts, 0, len(sizes), alive, val, 0.0, True, tie, nb, kk, np.zeros(0), 1.0)
    assert sorted(got) == sorted(want)
    parts = [kr.select_clusters(starts, a, b, alive, val, 0.0, True, tie, nb, kk, np.zeros(0), 1.0)
             for a, b in [(0, 7), (7, 8), (8, 30)]]
    np.testing.assert_array_equal(np.concatenate(parts), got)  # cluster ranges do not change the result
    # with a threshold instead of a target
    pool = np.flatnonzero(alive & (val <= 0.4))
    cand = pool[np.lexsort((tie[pool], val[pool]))]
    got = kr.select_clusters(starts, 0, len(sizes), alive, val, 0.4, False, tie, nb, kk, np.zeros(0), 1.0)
    assert sorted(got) == sorted(_first_independent(cand, nb.astype(np.int64), n, kk))
    # the candidates' order: (val, tie), whatever order a sort leaves equal values in
    keys = val[pool]
    o = np.argsort(keys)
    c2 = pool[o]
    kr.break_ties(c2, keys[o], tie)
    np.testing.assert_array_equal(c2, cand)


def test_select_clusters_with_coverage_is_the_filtered_pass():
    rng = np.random.default_rng(8)
    sizes = rng.integers(10, 50, 20)
    starts = np.r_[0, np.cumsum(sizes)]
    n = int(starts[-1])
    K = 5
    cl = np.repeat(np.arange(len(sizes)), sizes)
    P = rng.random((n, 3)) + cl[:, None]
    d = ((P[:, None, :] - P[None, :, :]) ** 2).sum(axis=2)
    d[cl[:, None] != cl[None, :]] = np.inf
    np.fill_diagonal(d, np.inf)
    nb = np.argsort(d, axis=1)[:, :K].astype(np.int32)  # lists inside the clusters, nearest first
    kk = np.full(n, K, dtype=np.int64)
    alive = np.ones(n, dtype=bool)
    val = rng.random(n)
    tie = np.arange(n)
    r1 = np.sqrt(((P - P[nb[:, 0]]) ** 2).sum(axis=1))
    cand = np.argsort(val, kind="stable")
    ok = _covered(P, nb.astype(np.int64), cand, 1.0, kk)
    want = _first_independent(cand[ok], nb.astype(np.int64), n, kk)
    got = kr.select_clusters(starts, 0, len(sizes), alive, val, 0.0, True, tie, nb, kk, r1, 1.0)
    assert sorted(got) == sorted(want)


@pytest.mark.parametrize("seed", range(3))
def test_radix_order_is_the_stable_argsort(seed):
    """The rounds' radix sort of float keys (read as their bits): numpy's stable argsort, -0.0 equal to 0.0."""
    rng = np.random.default_rng(seed)
    m = 3000
    keys = rng.standard_normal(m + 7) * 10.0 ** rng.integers(-200, 200)
    keys[rng.integers(0, m, 400)] = keys[rng.integers(0, m, 400)]  # ties
    keys[:60] = np.r_[0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324][rng.integers(0, 6, 60)]
    scratch = (np.empty(m, np.uint64), np.empty(m, np.uint64), np.empty(m, np.int64), np.empty(m, np.int64),
               np.empty(256, np.int64))
    got = kr._radix_order(keys, m, *scratch)
    np.testing.assert_array_equal(got, np.argsort(keys[:m] + 0.0, kind="stable"))
