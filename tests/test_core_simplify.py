"""simplify_points: invariances, duplicates, errors, thread count; unit_free_scores, prune and
refine_labels give the same results on any thread count."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core import prune, refine_labels, simplify_points, unit_free_scores
from cloudsieve.errors import InvalidParameterError


def surface(n, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(6 * u[:, 0]) * np.cos(4 * u[:, 1])]


@pytest.mark.parametrize("method", ["km", "fcm"])
@pytest.mark.parametrize("rule,kw", [("threshold", {}), ("iterative", {}), ("target", dict(ratio=0.5)),
                                     ("iterative", dict(count=1500)), ("coverage", dict(ratio=0.5))])
def test_simplify_points_invariant_to_order_and_units(method, rule, kw):
    pts = surface(3000, seed=1)
    perm = np.random.default_rng(2).permutation(len(pts))
    kept = simplify_points(pts, method=method, rule=rule, cluster_size=300, **kw)
    assert kept.dtype == np.int64 and (np.diff(kept) > 0).all()
    if rule == "threshold":
        assert 0 < len(kept) < len(pts)
    for other, back in [(pts[perm], perm), (pts * 1000.0, np.arange(len(pts)))]:
        k2 = simplify_points(other, method=method, rule=rule, cluster_size=300, **kw)
        np.testing.assert_array_equal(np.sort(back[k2]), kept)


def test_duplicates_are_dropped():
    pts = surface(1000)
    dup = np.concatenate([pts, pts[:50]])
    # the copies are kept only when asked (keep_duplicates), whatever the rule
    kept = simplify_points(dup, method="km", rule="target", ratio=1.0, cluster_size=200, keep_duplicates=True)
    assert len(kept) == 1050  # ratio 1: nothing goes, and the copies stay with their first point
    kept = simplify_points(dup, method="km", rule="target", ratio=1.0, cluster_size=200)
    assert len(kept) == 1000  # by default the copies go even when nothing else does (S >= 0)
    kept = simplify_points(dup, method="km", rule="threshold", threshold=0.0, cluster_size=200)
    assert not np.isin(np.arange(1000, 1050), kept).any()


def test_bad_input_messages():
    pts = surface(100)
    with pytest.raises(InvalidParameterError, match=r"cluster_size=5 is too small: .* k_min\+2=6 points"):
        simplify_points(pts, cluster_size=5)
    with pytest.raises(ValueError, match=r"cluster_size=7 is too small: .* k_min\+2=8"):
        refine_labels(pts, "km", 7, k_min=6)
    bad = pts.copy()
    bad[10, 2] = np.nan
    with pytest.raises(ValueError, match=r"1 non-finite .* index 10"):
        simplify_points(bad)
    with pytest.raises(ValueError, match=r"shape \(n, d\), got shape \(300,\)"):
        simplify_points(pts.ravel())
    with pytest.raises(ValueError, match=r"rule must be one of iterative, threshold, target, coverage, eliminate, got 'x'"):
        simplify_points(pts, rule="x")
    with pytest.raises(ValueError, match=r"method must be one of fcm, km, got 'dbscan'"):
        simplify_points(pts, method="dbscan")
    with pytest.raises(ValueError, match=r"rule 'target' needs a ratio or a count"):
        simplify_points(pts, rule="target")
    with pytest.raises(ValueError, match=r"ratio must be a number in \(0, 1\], got 1.5"):
        simplify_points(pts, rule="target", ratio=1.5)
    with pytest.raises(ValueError, match=r"give ratio or count, not both"):
        simplify_points(pts, rule="target", ratio=0.5, count=3)
    with pytest.raises(ValueError, match=r"n_clusters=3 but the input has only 2 points"):
        from cloudsieve.core import KMeans

        KMeans(3).fit(pts[:2])


@pytest.mark.parametrize("method", ["km", "fcm"])
def test_threads_do_not_change_results(method):
    pts = surface(2000, seed=3)
    lab1 = refine_labels(pts, method, 200, seed=1, threads=1)
    lab2 = refine_labels(pts, method, 200, seed=1, threads=2)
    assert np.array_equal(lab1, lab2)
    assert np.array_equal(unit_free_scores(pts, lab1, threads=1), unit_free_scores(pts, lab1, threads=2))
    for rule, kw in [("iterative", {}), ("threshold", {}), ("target", {"ratio": 0.5}), ("coverage", {"ratio": 0.6})]:
        k1 = prune(pts, lab1, rule=rule, threads=1, **kw)
        k2 = prune(pts, lab1, rule=rule, threads=2, **kw)
        assert np.array_equal(k1, k2), rule
    a = simplify_points(pts, method=method, cluster_size=200, seed=1, threads=1)
    b = simplify_points(pts, method=method, cluster_size=200, seed=1, threads=2)
    assert np.array_equal(a, b)


def test_the_point_check_against_the_rows_test():
    """check_points takes a finite sum for every coordinate finite: the rows' test (the obvious oracle) on
    NaN, +-inf, an inf beside a -inf (their sum NaN) and finite coordinates whose sum overflows."""
    import warnings

    from cloudsieve.core._validation import check_points
    from cloudsieve.errors import InvalidPointsError

    big = np.full((4, 3), 1e308)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning either
        assert check_points(big) is big
    for row, bad in ((0, [np.inf, -np.inf, 0.0]), (2, [0.0, np.nan, 0.0]), (3, [1e308, 1e308, -np.inf])):
        pts = big.copy()
        pts[row] = bad
        assert (~np.isfinite(pts).all(axis=1)).sum() == 1
        want = rf"points has 1 non-finite \(NaN or infinite\) rows, the first at index {row}:"
        with pytest.raises(InvalidPointsError, match=want):
            check_points(pts)
    assert check_points(np.zeros((0, 3))).shape == (0, 3)
