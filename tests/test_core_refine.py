"""refine_labels: KM or FCM labels into small clusters, the default stops."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core import refine_labels


def surface(n, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(6 * u[:, 0]) * np.cos(4 * u[:, 1])]


def test_refine_labels():
    pts = surface(2000)
    for method in ("km", "fcm"):
        lab = refine_labels(pts, method, 400, seed=3)
        assert lab.shape == (2000,) and lab.dtype == np.int64
        assert lab.min() >= 0 and lab.max() < 5


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")
def test_refine_labels_default_stops():
    """The refinement's defaults: KM and FCM stop at REFINE_LABEL_TOL (1%) of the
    hard labels changing, FCM after REFINE_FCM_MAX_ITER at most; label_tol=None
    with max_iter=300 is the paper's FCM."""
    from cloudsieve.core import FuzzyCMeans, KMeans
    from cloudsieve.core.refine import REFINE_FCM_MAX_ITER, REFINE_LABEL_TOL

    pts = surface(6000)
    km = KMeans(15, tol=REFINE_LABEL_TOL, seed=3).fit(pts)
    np.testing.assert_array_equal(refine_labels(pts, "km", 400, seed=3), km.labels_)
    f = FuzzyCMeans(15, max_iter=REFINE_FCM_MAX_ITER, label_tol=REFINE_LABEL_TOL, seed=3).fit(pts)
    assert f.n_iter_ < REFINE_FCM_MAX_ITER  # the 1% test, not the cap, stopped it
    np.testing.assert_array_equal(refine_labels(pts, "fcm", 400, seed=3), f.labels_)
    paper = FuzzyCMeans(15, max_iter=300, seed=3).fit(pts)
    np.testing.assert_array_equal(refine_labels(pts, "fcm", 400, seed=3, max_iter=300, label_tol=None), paper.labels_)
