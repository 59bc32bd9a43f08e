"""nearest_centres: the same arrays as scipy's cKDTree (ties, duplicates, outliers, any p), whatever the threads."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core import centres as ce
from cloudsieve.core.kernels.kmeans import pairwise_sum
from cloudsieve.core.kernels.threads import Chunks


def tree_answer(X, C, k):
    d, i = ce.centre_tree(C).query(X, k=k)
    return d.reshape(len(X), k), i.reshape(len(X), k)


def cloud(rng, n, p, scale):
    s = np.resize(np.asarray(scale, dtype=np.float64), p)
    return rng.random((n, p)) * s * 1.2 - 0.1 * s, s  # some points outside the centres' box


@pytest.mark.parametrize("p", [1, 2, 3, 5])
@pytest.mark.parametrize("scale", [(1, 1, 1), (100, 100, 1), (1, 1, 100)])
def test_nearest_centres_equal_the_tree(p, scale):
    rng = np.random.default_rng(p * 7 + int(scale[0]))
    X, s = cloud(rng, 6000, p, scale)
    C = rng.random((120, p)) * s
    C[5] = C[6]  # a duplicate centre
    X[:40] = np.round(X[:40] * 4) / 4  # points on a lattice, equidistant from lattice centres
    C[7:20] = np.round(C[7:20] * 4) / 4
    rows = np.arange(0, len(X), 3)
    for k in (1, 2, 17, 120):
        dd, ii = tree_answer(X, C, k)
        for f in (0.3, 1.0, 3.0):  # the cell side changes only the speed
            h = ce.cell_size(C, k) * f
            with Chunks(2) as chunks:
                d, i = ce.nearest_centres(X, C, k, chunks, h)  # many rows: candidate lists (p <= 3)
                dr, ir = ce.nearest_centres(X, C, k, chunks, h, rows)  # few rows: rings
            np.testing.assert_array_equal(d, dd)
            np.testing.assert_array_equal(dr, dd[rows])
            # the last column's index may be another centre at the same distance
            np.testing.assert_array_equal(i[:, : k - 1], ii[:, : k - 1])
            np.testing.assert_array_equal(ir[:, : k - 1], ii[rows, : k - 1])
            if k == len(C):
                np.testing.assert_array_equal(i, ii)


def test_nearest_centres_same_on_any_thread_count_and_with_far_outliers():
    rng = np.random.default_rng(11)
    X = rng.random((50_000, 3)) * [50.0, 50.0, 2.0]
    X[:3] = [[1e7, 0, 0], [-1e6, 5, 5], [3, 3, 1e5]]
    C = X[rng.choice(len(X), 200, replace=False)] + 1e-3
    dd, ii = tree_answer(X, C, 9)
    out = []
    for t in (1, 2, 3):
        with Chunks(t) as chunks:
            out.append(ce.nearest_centres(X, C, 9, chunks, ce.cell_size(C, 9)))
    for d, i in out:
        np.testing.assert_array_equal(d, dd)
        np.testing.assert_array_equal(i[:, :8], ii[:, :8])
        np.testing.assert_array_equal(i, out[0][1])


def test_pairwise_sum_is_numpys_row_sum():
    rng = np.random.default_rng(0)
    for n in [0, 1, 3, 7, 8, 9, 15, 16, 17, 64, 127, 128, 129, 200, 513, 1000, 4097]:
        a = rng.random((3, n)) * np.exp(rng.normal(size=(3, n)) * 8)
        want = a.sum(axis=1)
        for r in range(3):
            assert 0.0 + pairwise_sum(a[r], 0, n) == want[r]


def test_chunks_cover_the_range_in_order():
    with Chunks(3) as chunks:
        got = chunks.map(lambda s, e: (s, e), 100_000, min_chunk=1000)
    assert got[0][0] == 0 and got[-1][1] == 100_000
    assert all(a[1] == b[0] for a, b in zip(got, got[1:]))
    with Chunks(1) as chunks:
        assert chunks.map(lambda s, e: (s, e), 10) == [(0, 10)]
