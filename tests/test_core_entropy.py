"""entropy_scores against a brute-force leave-one-out oracle, and its invariances."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloudsieve.core import entropy_scores, neighbour_count, score_points
from cloudsieve.errors import InvalidParameterError, InvalidPointsError


def oracle(P, k0=1.0, k_min=4, dim=3, context=None):
    """|H(R) - H(R minus y)| recomputed from scratch for every y, in long double.

    r_k(x) is the k-th smallest distance from x to the other points of R (and
    of the context, if any); k is fixed from m = len(P).
    """
    m = len(P)
    k = max(k_min, int(np.floor(k0 * np.sqrt(m) + 0.5)))
    pool = P if context is None else np.concatenate([P, context])
    D = np.sqrt(((P[:, None, :] - pool[None, :, :]) ** 2).sum(-1))
    D[np.arange(m), np.arange(m)] = np.inf  # a point is not its own neighbour

    def H(rows):
        cols = np.r_[rows, np.arange(m, len(pool))]
        rk = np.sort(D[np.ix_(rows, cols)], axis=1)[:, k - 1].astype(np.longdouble)
        w = rk ** (-dim)
        p = w / w.sum()
        return -(p * np.log(p)).sum()

    everyone = np.arange(m)
    h = H(everyone)
    return np.array([abs(h - H(np.delete(everyone, y))) for y in range(m)], dtype=np.float64)


def _clusters(rng, dim, lattice):
    sizes = rng.integers(20, 301, size=4)
    parts = []
    for j, m in enumerate(sizes):
        if lattice:  # integer coordinates: many exactly equal distances (ties), no duplicates
            side = int(np.ceil(m ** (1 / dim))) + 3
            cells = rng.choice(side**dim, size=m, replace=False)
            p = np.stack(np.unravel_index(cells, (side,) * dim), axis=1).astype(float)
        else:
            p = rng.random((m, dim)) * rng.uniform(0.5, 5)
        parts.append(p + 100.0 * j)
    labels = np.repeat(np.arange(len(sizes)) * 7 + 3, sizes)  # arbitrary label values
    pts = np.concatenate(parts)
    perm = rng.permutation(len(pts))  # clusters interleaved in the input
    return pts[perm], labels[perm]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("lattice", [False, True], ids=["random", "ties"])
def test_matches_brute_force_oracle(dim, lattice):
    rng = np.random.default_rng(10 * dim + lattice)
    pts, labels = _clusters(rng, dim, lattice)
    got = entropy_scores(pts, labels, dim=dim)
    for lab in np.unique(labels):
        sel = labels == lab
        want = oracle(pts[sel], dim=dim)
        # relative error <= 1e-9; the tiny atol is the long-double oracle's own floor
        np.testing.assert_allclose(got[sel], want, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("k0,k_min", [(0.5, 3), (2.0, 4), (1.0, 10)])
def test_oracle_other_k(k0, k_min):
    rng = np.random.default_rng(5)
    pts = rng.random((120, 3))
    np.testing.assert_allclose(entropy_scores(pts, k0=k0, k_min=k_min), oracle(pts, k0, k_min), rtol=1e-9, atol=1e-15)


def test_context_matches_oracle():
    rng = np.random.default_rng(7)
    a = rng.random((80, 3))
    b = rng.random((60, 3)) + [0.5, 0, 0]
    ctx = rng.random((50, 3)) + [0, 0.7, 0]
    pts = np.concatenate([a, b])
    labels = np.r_[np.zeros(80, int), np.ones(60, int)]
    got = entropy_scores(pts, labels, context=np.concatenate([ctx, a[:5]]))  # copies of points are ignored
    # in context mode every point (of any cluster) and the context are density neighbours
    np.testing.assert_allclose(got[:80], oracle(a, context=np.concatenate([b, ctx])), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(got[80:], oracle(b, context=np.concatenate([a, ctx])), rtol=1e-9, atol=1e-15)


def test_duplicates_score_zero_and_are_counted():
    rng = np.random.default_rng(3)
    base = rng.random((100, 3))
    pts = np.concatenate([base, base[[4, 4, 17]]])
    s = score_points(pts)
    assert s.n_duplicates == 3
    assert s.duplicate[100:].all() and not s.duplicate[:100].any()
    assert (s.delta_h[100:] == 0).all()
    np.testing.assert_allclose(s.delta_h[:100], oracle(base), rtol=1e-9, atol=1e-15)


def test_small_clusters_get_inf():
    rng = np.random.default_rng(0)
    pts = rng.random((40, 3))
    labels = np.r_[np.zeros(34, int), np.ones(6, int)]  # 6 = k_min + 2: scored
    s = entropy_scores(pts, labels)
    assert np.isfinite(s).all()
    labels[-1] = 2  # cluster 1 now has 5 < k_min + 2 points
    s = entropy_scores(pts, labels)
    assert np.isinf(s[34:]).all() and np.isfinite(s[:34]).all()


def test_unit_free_and_k():
    rng = np.random.default_rng(1)
    pts = rng.random((150, 3))
    labels = np.r_[np.zeros(100, int), np.ones(50, int)]
    s = score_points(pts, labels)
    assert (s.cluster_size == np.r_[np.full(100, 100), np.full(50, 50)]).all()
    assert (s.k == np.r_[np.full(100, 10), np.full(50, 7)]).all()
    np.testing.assert_array_equal(s.unit_free, s.delta_h * s.cluster_size)
    assert int(neighbour_count(400)) == 20 and int(neighbour_count(9)) == 4


@pytest.mark.parametrize("factor", [1000.0, 1024.0, 1e-3])
def test_invariant_to_units(factor):
    rng = np.random.default_rng(2)
    pts = rng.random((500, 3))
    labels = rng.integers(0, 3, 500)
    np.testing.assert_allclose(entropy_scores(pts * factor, labels), entropy_scores(pts, labels), rtol=1e-10)


def test_invariant_to_order():
    rng = np.random.default_rng(4)
    pts = rng.integers(0, 9, (400, 3)).astype(float)  # ties and duplicates
    labels = rng.integers(0, 2, 400)
    perm = rng.permutation(400)
    a = entropy_scores(pts, labels)
    b = entropy_scores(pts[perm], labels[perm])
    fin = np.isfinite(a[perm])
    # duplicates: which copy scores 0 follows the order, so compare the sorted scores per coordinate
    keys = np.lexsort((a[perm], *pts[perm].T))
    keys_b = np.lexsort((b, *pts[perm].T))
    np.testing.assert_allclose(a[perm][keys], b[keys_b], rtol=1e-12)
    assert fin.all()


def test_bad_input_messages():
    with pytest.raises(InvalidPointsError, match=r"1 non-finite .* index 2"):
        entropy_scores(np.array([[0, 0, 0], [1, 1, 1], [np.nan, 0, 0.0]]))
    with pytest.raises(ValueError, match=r"shape \(n, d\), got shape \(5,\)"):
        entropy_scores(np.zeros(5))
    with pytest.raises(InvalidParameterError, match=r"labels must have shape \(3,\).*\(2,\)"):
        entropy_scores(np.zeros((3, 3)), labels=[0, 1])
    with pytest.raises(ValueError, match=r"k_min must be an integer >= 1, got 0"):
        entropy_scores(np.zeros((3, 3)), k_min=0)


@settings(max_examples=25, deadline=None)
@given(m=st.integers(6, 60), seed=st.integers(0, 2**32 - 1), grid=st.booleans())
def test_property_matches_oracle_and_is_order_free(m, seed, grid):
    rng = np.random.default_rng(seed)
    pts = rng.integers(0, 5, (m, 3)).astype(float) if grid else rng.random((m, 3))
    s = score_points(pts)
    perm = rng.permutation(m)
    sp = score_points(pts[perm])
    assert s.n_duplicates == sp.n_duplicates
    distinct = pts[~s.duplicate]
    if len(distinct) >= neighbour_count(len(distinct)) + 2:
        np.testing.assert_allclose(s.delta_h[~s.duplicate], oracle(distinct), rtol=1e-9, atol=1e-15)
    else:
        assert np.isinf(s.delta_h[~s.duplicate]).all()
    np.testing.assert_allclose(np.sort(sp.delta_h), np.sort(s.delta_h), rtol=1e-12)


@pytest.mark.parametrize("values", [(0, 1, 2, 3, 4, 5), (-3, 7, 10**9, 2, 5, 6)])
def test_clusters_scored_as_separate_clouds(values):
    # overlapping clusters (random labels), copies, one small cluster, sparse label values:
    # one k-d tree over all the clusters must give each cluster's own scores and graph
    rng = np.random.default_rng(11)
    pts = rng.random((1500, 3))
    labels = np.asarray(values)[rng.integers(0, 5, 1500)]
    labels[:8] = values[5]  # a cluster of 8 points, 3 distinct: too small to score (needs k + 2 = 6)
    pts[:8] = pts[[0, 1, 2, 0, 1, 2, 0, 1]]
    pts[100:130] = pts[200:230]
    labels[100:130] = labels[200:230]
    s = score_points(pts, labels)
    for v in values:
        idx = np.flatnonzero(labels == v)
        r = score_points(pts[idx], None)
        np.testing.assert_allclose(s.delta_h[idx], r.delta_h, rtol=1e-12)
        np.testing.assert_array_equal(s.duplicate[idx], r.duplicate)
        np.testing.assert_array_equal(s.k[idx], r.k)
        nb = s.neighbours[idx]
        back = np.where(r.neighbours >= 0, idx[np.maximum(r.neighbours, 0)], -1)
        np.testing.assert_array_equal(nb[:, : back.shape[1]], back)
        assert (nb[:, back.shape[1] :] == -1).all()
    assert s.n_duplicates == 5 + 30
    assert np.isinf(s.delta_h[:3]).all() and (s.delta_h[3:8] == 0).all()
