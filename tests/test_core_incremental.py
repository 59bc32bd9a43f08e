"""The rounds without context (core/incremental.py): the result does not depend on the thread count."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core import prune, refine_labels


@pytest.mark.parametrize("rule,kw", [("iterative", dict(ratio=0.5)), ("coverage", dict(ratio=0.4)),
                                     ("iterative", dict(threshold=2e-3))])
def test_rounds_do_not_depend_on_threads(rule, kw):
    rng = np.random.default_rng(11)
    u = rng.random((6000, 2))
    pts = np.c_[u, 0.05 * np.sin(5 * u[:, 0])]
    pts = np.round(pts * 512) / 512  # quantised, as LAS coordinates: tied distances
    pts = np.concatenate([pts, pts[:60]])  # and exact copies
    labels = refine_labels(pts, "km", 200, seed=0)
    masks = [prune(pts, labels, rule=rule, threads=t, **kw) for t in (1, 2, 5)]
    np.testing.assert_array_equal(masks[0], masks[1])
    np.testing.assert_array_equal(masks[0], masks[2])
