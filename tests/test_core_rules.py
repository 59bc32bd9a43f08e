"""The pruning rules' contracts: threshold, target, the rounds of iterative and coverage."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core import exact_copies, prune, refine_labels, score_points, threshold_for_count, unit_free_scores
from cloudsieve.core.rounds import _first_independent, _padded
from cloudsieve.errors import InvalidParameterError


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


def _reference_rounds(pts, labels, rule, S=1e-3, target=None, coverage=1.0):
    """The iterative/coverage rules by full rescoring of the remaining points every round.

    Exact copies go first, as in every rule (the rules run on the distinct points).
    """
    from cloudsieve.core.knn import canonical_order
    from cloudsieve.core.rounds import _covered

    order = canonical_order(pts)
    P, L = pts[order], labels[order]
    alive = np.flatnonzero(~exact_copies(P))  # canonical order: the first of each copy group stays
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


# ----------------------------------------------------------------- eliminate


def test_eliminate_rule_is_the_core_eliminate_with_an_exact_count():
    from cloudsieve.core import simplify_points
    from cloudsieve.core.eliminate import eliminate

    rng = np.random.default_rng(5)
    pts = np.c_[rng.random((3_000, 2)) * 10, rng.normal(0, 0.01, 3_000)]
    kept = simplify_points(pts, rule="eliminate", ratio=0.25, method="fcm", cluster_size=50)
    assert len(kept) == 750
    assert np.array_equal(kept, eliminate(pts, ratio=0.25))
    assert np.array_equal(simplify_points(pts, rule="eliminate", count=750), kept)
    mask = prune(pts, rule="eliminate", count=750)
    assert np.array_equal(np.flatnonzero(mask), kept)


def test_eliminate_rule_needs_a_ratio_or_a_count():
    from cloudsieve.core import simplify_points

    pts = np.random.default_rng(0).random((100, 3))
    with pytest.raises(InvalidParameterError, match="rule 'eliminate' needs a ratio or a count"):
        simplify_points(pts, rule="eliminate")
    with pytest.raises(InvalidParameterError, match="rule 'eliminate' needs a ratio or a count"):
        prune(pts, rule="eliminate")
