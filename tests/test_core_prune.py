"""The pruning rules' contracts, simplify_points' invariances, refine_labels, errors."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.entropy import score_points
from cloudsieve.errors import InvalidParameterError
from cloudsieve.core.prune import (
    _first_independent,
    _padded,
    prune,
    refine_labels,
    simplify_points,
    threshold_for_count,
    unit_free_scores,
)


def surface(n, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(6 * u[:, 0]) * np.cos(4 * u[:, 1])]


@pytest.fixture(scope="module")
def cloud():
    pts = surface(3000)
    labels = refine_labels(pts, "km", 300, seed=0)
    return pts, labels


def test_threshold_rule_contract(cloud):
    pts, labels = cloud
    dh = score_points(pts, labels).delta_h
    S = float(np.quantile(dh, 0.3))
    keep = prune(pts, labels, rule="threshold", threshold=S)
    assert (dh[~keep] <= S).all() and (dh[keep] > S).all()
    assert 0 < (~keep).sum() < len(pts)
    # on the unit-free score
    uf = unit_free_scores(pts, labels)
    t = float(np.median(uf))
    keep = prune(pts, labels, rule="threshold", threshold=t, score="unit_free")
    assert (uf[~keep] <= t).all() and (uf[keep] > t).all()


def _adjacent(s, a, b):
    """Is b among a's k nearest (CSR of Scores s)?"""
    return b in s.indices[s.indptr[a] : s.indptr[a + 1]]


def test_iterative_rule_rounds_are_independent_sets(cloud):
    pts, labels = cloud
    S = float(np.quantile(score_points(pts, labels).delta_h, 0.5))
    alive = np.arange(len(pts))
    for rnd in range(1, 4):
        s = score_points(pts[alive], labels[alive])
        before = prune(pts, labels, rule="iterative", threshold=S, max_rounds=rnd - 1)
        after = prune(pts, labels, rule="iterative", threshold=S, max_rounds=rnd)
        assert (before[alive]).all() and before.sum() == len(alive)
        dropped = np.flatnonzero(before & ~after)  # this round, input indices
        pos = np.searchsorted(alive, dropped)
        cand = np.flatnonzero(s.delta_h <= S)
        assert set(pos) <= set(cand)
        assert len(pos) > 0
        dset = set(pos.tolist())
        for a in pos:  # no two dropped points are k-NN neighbours, either way
            nb = set(s.indices[s.indptr[a] : s.indptr[a + 1]].tolist())
            assert not (nb & dset)
        for y in set(cand.tolist()) - dset:  # maximal: a kept candidate has a dropped neighbour
            nb = set(s.indices[s.indptr[y] : s.indptr[y + 1]].tolist())
            assert (nb & dset) or any(_adjacent(s, a, y) for a in pos)
        alive = np.flatnonzero(after)
    final = prune(pts, labels, rule="iterative", threshold=S)
    s = score_points(pts[final], labels[final])
    assert (s.delta_h > S).all()  # stops when no point qualifies


def test_first_independent_is_the_sequential_greedy():
    rng = np.random.default_rng(0)
    n, k = 300, 5
    indices = rng.integers(0, n, n * k)
    indptr = np.arange(0, n * k + 1, k)
    cand = rng.permutation(n)[:200]
    got = _first_independent(cand, _padded(indptr, indices), n)
    taken = []
    blocked = np.zeros(n, bool)
    nbrs = [set(indices[indptr[i] : indptr[i + 1]].tolist()) for i in range(n)]
    for c in cand:
        if not blocked[c] and not (nbrs[c] & set(taken)):
            taken.append(c)
            blocked[list(nbrs[c])] = True
    np.testing.assert_array_equal(got, taken)


@pytest.mark.parametrize("rule", ["target", "iterative", "coverage"])
@pytest.mark.parametrize("req", [dict(ratio=0.5), dict(ratio=0.9), dict(count=1234)])
def test_target_count(cloud, rule, req):
    pts, labels = cloud
    keep = prune(pts, labels, rule=rule, **req)
    want = req.get("count", round(req.get("ratio", 0) * len(pts)))
    assert abs(keep.sum() - want) <= 0.01 * want


def test_target_drops_lowest_unit_free(cloud):
    pts, labels = cloud
    uf = unit_free_scores(pts, labels)
    keep = prune(pts, labels, rule="target", ratio=0.6)
    assert uf[~keep].max() <= uf[keep].min()
    t = threshold_for_count(uf, int((~keep).sum()))
    assert t == uf[~keep].max()


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
    kept = simplify_points(dup, method="km", rule="threshold", threshold=-1.0, cluster_size=200)
    assert len(kept) == 1050  # S < 0: nothing qualifies, not even the copies (score 0)
    kept = simplify_points(dup, method="km", rule="threshold", threshold=0.0, cluster_size=200)
    assert not np.isin(np.arange(1000, 1050), kept).any()


def test_refine_labels():
    pts = surface(2000)
    for method in ("km", "fcm"):
        lab = refine_labels(pts, method, 400, seed=3)
        assert lab.shape == (2000,) and lab.dtype == np.int64
        assert lab.min() >= 0 and lab.max() < 5


@pytest.mark.filterwarnings("ignore::cloudsieve.core.cluster.ConvergenceWarning")
def test_refine_labels_default_stops():
    """The refinement's defaults: KM and FCM stop at REFINE_LABEL_TOL (1%) of the
    hard labels changing, FCM after REFINE_FCM_MAX_ITER at most; label_tol=None
    with max_iter=300 is the paper's FCM."""
    from cloudsieve.core.cluster import FuzzyCMeans, KMeans
    from cloudsieve.core.prune import REFINE_FCM_MAX_ITER, REFINE_LABEL_TOL

    pts = surface(6000)
    km = KMeans(15, tol=REFINE_LABEL_TOL, seed=3).fit(pts)
    np.testing.assert_array_equal(refine_labels(pts, "km", 400, seed=3), km.labels_)
    f = FuzzyCMeans(15, max_iter=REFINE_FCM_MAX_ITER, label_tol=REFINE_LABEL_TOL, seed=3).fit(pts)
    assert f.n_iter_ < REFINE_FCM_MAX_ITER  # the 1% test, not the cap, stopped it
    np.testing.assert_array_equal(refine_labels(pts, "fcm", 400, seed=3), f.labels_)
    paper = FuzzyCMeans(15, max_iter=300, seed=3).fit(pts)
    np.testing.assert_array_equal(refine_labels(pts, "fcm", 400, seed=3, max_iter=300, label_tol=None), paper.labels_)


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
    with pytest.raises(ValueError, match=r"rule must be one of iterative, threshold, target, coverage, got 'x'"):
        simplify_points(pts, rule="x")
    with pytest.raises(ValueError, match=r"method must be 'fcm' or 'km', got 'dbscan'"):
        simplify_points(pts, method="dbscan")
    with pytest.raises(ValueError, match=r"rule='target' needs ratio="):
        simplify_points(pts, rule="target")
    with pytest.raises(ValueError, match=r"ratio is the kept fraction, in \[0, 1\], got 1.5"):
        simplify_points(pts, rule="target", ratio=1.5)
    with pytest.raises(ValueError, match=r"give ratio or count, not both"):
        simplify_points(pts, rule="target", ratio=0.5, count=3)
    with pytest.raises(ValueError, match=r"n_clusters=3 but the input has only 2 points"):
        from cloudsieve.core.cluster import KMeans

        KMeans(3).fit(pts[:2])


def test_coverage_keeps_isolated_points_that_iterative_drops():
    rng = np.random.default_rng(8)
    plane = np.c_[rng.random((2000, 2)), np.zeros(2000)]
    outliers = np.array([[0.5, 0.5, 0.3], [0.2, 0.7, -0.25], [0.9, 0.1, 0.4]])
    pts = np.concatenate([plane, outliers])
    labels = np.zeros(len(pts), dtype=np.int64)
    uf = unit_free_scores(pts, labels)
    assert (uf[2000:] < np.median(uf[:2000])).all()  # |dH| calls the outliers redundant
    it = prune(pts, labels, rule="iterative", ratio=0.5)
    cov = prune(pts, labels, rule="coverage", ratio=0.5)
    assert not it[2000:].any()
    assert cov[2000:].all()
    assert abs(cov.sum() - 1002) <= 10


def test_coverage_with_threshold_is_a_subset_rule(cloud):
    pts, labels = cloud
    S = float(np.quantile(score_points(pts, labels).delta_h, 0.5))
    first = prune(pts, labels, rule="coverage", threshold=S, max_rounds=1)
    s = score_points(pts, labels)
    assert (s.delta_h[~first] <= S).all()
    kept_it = prune(pts, labels, rule="iterative", threshold=S, max_rounds=1)
    assert (~first).sum() < (~kept_it).sum()  # the coverage test only removes candidates


@pytest.mark.parametrize("method", ["km", "fcm"])
def test_workers_do_not_change_results(method):
    pts = surface(2000, seed=3)
    lab1 = refine_labels(pts, method, 200, seed=1, workers=1)
    lab2 = refine_labels(pts, method, 200, seed=1, workers=2)
    assert np.array_equal(lab1, lab2)
    assert np.array_equal(unit_free_scores(pts, lab1, workers=1), unit_free_scores(pts, lab1, workers=2))
    for rule, kw in [("iterative", {}), ("threshold", {}), ("target", {"ratio": 0.5}), ("coverage", {"ratio": 0.6})]:
        k1 = prune(pts, lab1, rule=rule, workers=1, **kw)
        k2 = prune(pts, lab1, rule=rule, workers=2, **kw)
        assert np.array_equal(k1, k2), rule
    a = simplify_points(pts, method=method, cluster_size=200, seed=1, workers=1)
    b = simplify_points(pts, method=method, cluster_size=200, seed=1, workers=2)
    assert np.array_equal(a, b)


def _reference_rounds(pts, labels, rule, S=1e-3, target=None, coverage=1.0):
    """The iterative/coverage rules by full rescoring of the remaining points every round."""
    from cloudsieve.core.cluster import _canonical_order
    from cloudsieve.core.prune import _covered

    order = _canonical_order(pts)
    P, L = pts[order], labels[order]
    alive = np.arange(len(pts))
    while target is None or len(alive) > target:
        s = score_points(P[alive], L[alive])
        val = s.delta_h if target is None else s.unit_free
        pool = np.flatnonzero(val <= S if target is None else np.isfinite(val))
        cand = pool[np.lexsort((pool, val[pool]))]
        if rule == "coverage" and len(cand):
            cand = cand[_covered(P[alive], s.neighbours, cand, coverage)]
        if len(cand) == 0:
            break
        sel = _first_independent(cand, s.neighbours, len(alive))
        if target is not None:
            sel = sel[: len(alive) - target]
        alive = np.delete(alive, sel)
    keep = np.zeros(len(pts), dtype=bool)
    keep[order[alive]] = True
    return keep


@pytest.mark.parametrize("rule,kw", [("iterative", dict(ratio=0.4)), ("coverage", dict(ratio=0.5)),
                                     ("iterative", dict(threshold="q30")), ("coverage", dict(count=2500))])
def test_incremental_rounds_equal_full_rescoring(rule, kw):
    # clusters whose k falls round after round, exact copies, a small cluster: the incremental
    # rescoring between rounds must keep exactly the points a full rescoring keeps
    pts = surface(3000, seed=5)
    labels = refine_labels(pts, "km", 150, seed=0)
    pts = np.concatenate([pts, pts[:40], pts[:5] + 2.0])
    labels = np.concatenate([labels, labels[:40], np.full(5, labels.max() + 1)])
    kw = dict(kw)
    if kw.get("threshold") == "q30":
        kw["threshold"] = float(np.quantile(score_points(pts, labels).delta_h, 0.3))
    n = len(pts)
    target = round(kw["ratio"] * n) if "ratio" in kw else kw.get("count")
    ref = _reference_rounds(pts, labels, rule, S=kw.get("threshold", 1e-3), target=target)
    got = prune(pts, labels, rule=rule, **kw)
    np.testing.assert_array_equal(got, ref)
    assert got[-5:].all()  # the small cluster (5 < k + 2 = 6) is never scored


def test_first_independent_with_row_lengths():
    rng = np.random.default_rng(1)
    n, k = 400, 6
    nb = rng.integers(0, n, (n, k))
    nb[nb == np.arange(n)[:, None]] = -1  # no self loops
    kk = rng.integers(0, k + 1, n)
    cut = np.where(np.arange(k) < kk[:, None], nb, -1)
    cand = rng.permutation(n)[:300]
    np.testing.assert_array_equal(_first_independent(cand, nb, n, kk), _first_independent(cand, cut, n))
    padded_n = np.where(cut < 0, n, cut)  # padding n works like -1
    np.testing.assert_array_equal(_first_independent(cand, padded_n, n), _first_independent(cand, cut, n))
