"""The k-NN lists kept between rounds (core/kernels/lists.py) against the k-d tree and brute force."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core._validation import neighbour_count
from cloudsieve.core.kernels import lists as kl
from cloudsieve.core.knn import group, knn_query

SPARE = 4


def clusters(rng, sizes, grid=None):
    """Points of clusters of the given sizes, grouped (g, ginv, starts); rounded to multiples of ``grid``."""
    pts = np.concatenate([rng.random((m, 3)) + 10.0 * j for j, m in enumerate(sizes)])
    if grid:
        pts = np.round(pts / grid) * grid
        pts[1:40:3] = pts[0:39:3]  # and exact copies
    lab = np.repeat(np.arange(len(sizes)), sizes)
    inv, order, sz = group(pts, lab)
    starts = np.zeros(len(sz) + 1, dtype=np.int64)
    np.cumsum(sz, out=starts[1:])
    return pts[order], inv[order], starts


def tree_lists(g, ginv, rows, kcl):
    """{row: (k, r_k, r_(k+1), list)} from the k-d tree query of knn_query (cKDTree)."""
    groups, flagged = knn_query(g, ginv, rows, kcl, 1, extra=SPARE)
    out = {}
    for k, r, a, b, x in groups:
        for i, row in enumerate(r):
            out[int(row)] = (k, a[i], b[i], x[i])
    return out, flagged


@pytest.mark.parametrize("keep", [1.0, 0.6])
def test_refresh_lists_equal_the_kd_tree(keep):
    rng = np.random.default_rng(3)
    sizes = rng.integers(8, 600, 12)
    g, ginv, starts = clusters(rng, sizes)
    n = len(g)
    alive = rng.random(n) < keep
    dup = np.zeros(n, dtype=bool)
    m = np.bincount(ginv[alive], minlength=len(sizes))
    kcl = np.where(m >= neighbour_count(m) + 2, neighbour_count(m), 0)
    rows = np.flatnonzero(alive & (kcl[ginv] > 0))
    width = int(kcl.max()) + 1 + SPARE
    lists, kq, rk, rk1, r1, status = kl.refresh_lists(g, ginv, starts, alive, dup, rows, kcl, SPARE, width)
    ref, flagged = tree_lists(g, ginv, rows, kcl)
    assert not flagged.any() and (status == 0).all()
    for i, row in enumerate(rows):
        k, a, b, x = ref[int(row)]
        assert kq[i] == k and rk[i] == a and rk1[i] == b  # bit for bit
        np.testing.assert_array_equal(lists[i, : len(x)], x)
        assert (lists[i, len(x) :] == n).all()
        assert r1[i] == np.sqrt(((g[row] - g[x[0]]) ** 2).sum())


def test_refresh_lists_flag_ties_and_copies():
    rng = np.random.default_rng(4)
    sizes = np.array([300, 200, 120])
    g, ginv, starts = clusters(rng, sizes, grid=1 / 256)  # quantised coordinates: equal distances, copies
    n = len(g)
    alive = np.ones(n, dtype=bool)
    kcl = neighbour_count(sizes)
    rows = np.arange(n)
    width = int(kcl.max()) + 1 + SPARE
    lists, kq, rk, rk1, r1, status = kl.refresh_lists(g, ginv, starts, alive, np.zeros(n, bool), rows, kcl, SPARE,
                                                      width)
    for i, y in enumerate(rows):
        members = np.arange(starts[ginv[y]], starts[ginv[y] + 1])
        others = members[members != y]
        d2 = np.sort(((g[others] - g[y]) ** 2).sum(axis=1))
        L = kcl[ginv[y]] + 1 + min(SPARE, len(members) - kcl[ginv[y]] - 2)
        head = d2[: L + 1]
        if head[0] == 0:
            assert status[i] == 2  # an exact copy: the k-d tree's duplicate handling decides
        elif (np.diff(head) == 0).any():
            assert status[i] == 1  # tied distances: the k-d tree's order decides
        else:
            assert status[i] == 0
            np.testing.assert_array_equal(((g[lists[i, :L]] - g[y]) ** 2).sum(axis=1), d2[:L])
    assert (status == 1).any() and (status == 2).any() and (status == 0).any()
    # where the list is unique, it is the tree's (the tree's rows, not only its distances)
    distinct = np.ones(n, dtype=bool)
    for j in range(len(sizes)):
        seg = g[starts[j] : starts[j + 1]]
        _, first = np.unique(seg, axis=0, return_index=True)
        mask = np.zeros(len(seg), dtype=bool)
        mask[first] = True
        distinct[starts[j] : starts[j + 1]] = mask
    rows2 = np.flatnonzero(distinct)
    lists2, kq2, rk_2, rk1_2, _, st2 = kl.refresh_lists(g, ginv, starts, distinct, np.zeros(n, bool), rows2,
                                                         neighbour_count(np.bincount(ginv[distinct])), SPARE, width)
    ref, flagged = tree_lists(g, ginv, rows2, neighbour_count(np.bincount(ginv[distinct])))
    assert not flagged.any()
    for i, row in enumerate(rows2):
        if st2[i] == 0:
            k, a, b, x = ref[int(row)]
            np.testing.assert_array_equal(lists2[i, : len(x)], x)
            assert (kq2[i], rk_2[i], rk1_2[i]) == (k, a, b)


def test_repack_lists_keep_the_nearest_remaining():
    rng = np.random.default_rng(5)
    sizes = np.array([150, 90, 400])
    g, ginv, starts = clusters(rng, sizes)
    n = len(g)
    kcl = neighbour_count(sizes)
    width = int(kcl.max()) + 1 + SPARE
    nb = np.full((n, width), n, dtype=np.int32)
    kk = np.zeros(n, dtype=np.int64)
    rk, rk1, r1 = np.ones(n), np.ones(n), np.full(n, np.inf)
    lists, kq, a, b, d1, st = kl.refresh_lists(g, ginv, starts, np.ones(n, bool), np.zeros(n, bool), np.arange(n),
                                               kcl, SPARE, width)
    kl.store_refreshed(np.arange(n), st, lists, kq, a, b, d1, kk, rk, rk1, r1, nb)
    removed = np.zeros(n + 1, dtype=bool)
    removed[rng.choice(n, n // 4, replace=False)] = True
    alive = ~removed[:n]
    m = np.bincount(ginv[alive], minlength=len(sizes))
    k_new = neighbour_count(m)
    nb[removed[:n]] = n
    kk[removed[:n]] = 0
    short = kl.repack_lists(g, ginv, kk, rk, rk1, r1, nb, np.ones(len(sizes), bool), k_new, removed, 0, n)
    for y in np.flatnonzero(alive):
        members = np.arange(starts[ginv[y]], starts[ginv[y] + 1])
        others = members[alive[members] & (members != y)]
        order = others[np.argsort(((g[others] - g[y]) ** 2).sum(axis=1), kind="stable")]
        entries = nb[y][nb[y] < n]
        np.testing.assert_array_equal(entries, order[: len(entries)])  # the nearest remaining, in order
        kn = k_new[ginv[y]]
        if y in short:
            assert len(entries) < kn + 1
        else:
            assert kk[y] == kn and len(entries) >= kn + 1
            assert rk[y] == np.sqrt(((g[y] - g[order[kn - 1]]) ** 2).sum())
            assert rk1[y] == np.sqrt(((g[y] - g[order[kn]]) ** 2).sum())
            assert r1[y] == np.sqrt(((g[y] - g[order[0]]) ** 2).sum())
