"""The merge's kernel (core/kernels/scatter.py): rows grouped by label back to input order."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.kernels.scatter import from_groups


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
