"""core/kernels/scatter.py: rows grouped by label (the in-memory cells' members) and back to input order (the merge)."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.kernels.scatter import from_groups, group_rows


@pytest.mark.parametrize("n, groups", [(0, 3), (1, 1), (1000, 7), (5000, 200)])
def test_from_groups_inverts_a_stable_sort_by_label(n, groups):
    """The oracle: the rows sorted stably by label are src; out[order] = src puts them back."""
    rng = np.random.default_rng(n)
    labels = rng.integers(0, groups, n).astype(np.int32)
    labels[labels == 1] = 2  # a label without rows
    order = np.argsort(labels, kind="stable")
    src = rng.random(n) < 0.5
    counts = np.bincount(labels, minlength=groups)
    offset = (np.cumsum(counts) - counts).astype(np.int64)
    expected = np.empty(n, dtype=bool)
    expected[order] = src
    assert np.array_equal(from_groups(labels, offset, src), expected)


@pytest.mark.parametrize("n, groups", [(0, 1), (1, 1), (5000, 1), (5000, 7), (2_100_001, 50)])
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_group_rows_is_numpy_s_stable_argsort(n, groups, threads):
    """The oracle: np.argsort(kind="stable") and the bincount's bounds, on any thread count (2.1 M rows: two
    and three ranges), with a label without rows."""
    rng = np.random.default_rng(n)
    labels = rng.integers(0, groups, n).astype(np.int64)
    labels[labels == 1] = 2
    order, bounds = group_rows(labels, groups, threads)
    assert np.array_equal(order, np.argsort(labels, kind="stable"))
    assert np.array_equal(bounds, np.r_[0, np.cumsum(np.bincount(labels, minlength=groups))])
