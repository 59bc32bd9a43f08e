"""KMeans and FuzzyCMeans: blobs, fixed points, dense-FCM oracle, invariances, errors."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core import ConvergenceWarning, FuzzyCMeans, KMeans
from cloudsieve.errors import InvalidParameterError, InvalidPointsError


def blobs(rng, c=6, per=150, spread=1.0, gap=100.0):
    centres = rng.random((c, 3)) * gap * c
    truth = np.repeat(np.arange(c), per)
    pts = centres[truth] + rng.normal(scale=spread, size=(c * per, 3))
    perm = rng.permutation(len(pts))
    return pts[perm], truth[perm]


def same_partition(a, b):
    """True when the labelings a and b define the same partition."""
    pairs = np.unique(np.stack([a, b], 1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


@pytest.mark.parametrize("init", ["k-means++", "random", "kd-split"])
@pytest.mark.parametrize("est", [KMeans, FuzzyCMeans])
def test_finds_well_separated_blobs(est, init):
    rng = np.random.default_rng(1)
    c = 2 if init == "random" else 4
    pts, truth = blobs(rng, c=c, gap=1000.0)
    # random init may put two centres in one blob (then no Lloyd step can fix it);
    # k-means++ on separated blobs does not
    seeds = range(10) if init == "random" else [0]
    ok = [same_partition(est(c, init=init, seed=s).fit(pts).labels_, truth) for s in seeds]
    assert any(ok) if init == "random" else all(ok)


def test_kmeans_is_a_lloyd_fixed_point():
    rng = np.random.default_rng(2)
    pts = rng.random((3000, 3))
    km = KMeans(30, seed=3).fit(pts)
    assert km.converged_
    C = km.cluster_centers_
    d = ((pts[:, None, :] - C[None]) ** 2).sum(-1)
    np.testing.assert_array_equal(km.labels_, d.argmin(1))  # every point at its nearest centre
    for j in range(30):
        np.testing.assert_allclose(C[j], pts[km.labels_ == j].mean(0), rtol=1e-12)


def plain_lloyd(X, C, max_iter):
    """Lloyd's algorithm on the full n x c distance matrix (the oracle): labels, centres, centre updates."""
    lab = None
    for it in range(1, max_iter + 1):
        new = ((X[:, None, :] - C[None]) ** 2).sum(-1).argmin(1)
        if lab is not None and (new == lab).all():
            return lab, C, it - 1
        lab = new
        cnt = np.bincount(lab, minlength=len(C))
        S = np.stack([np.bincount(lab, weights=X[:, j], minlength=len(C)) for j in range(X.shape[1])], 1)
        C = C.copy()
        C[cnt > 0] = S[cnt > 0] / cnt[cnt > 0, None]
    return lab, C, max_iter


@pytest.mark.parametrize("neigh", [1, 3, 8])
@pytest.mark.parametrize("init", ["random", "kd-split"])
def test_kmeans_equals_plain_lloyd(monkeypatch, neigh, init):
    # a wavy surface cut into many small clusters: the bounds skip most points,
    # the neighbour lists (few with neigh=1) are re-made and the k-d tree fallback is used
    import cloudsieve.core.cluster as cl
    import cloudsieve.core.kmeans as km
    from cloudsieve.core.knn import canonical_order

    monkeypatch.setattr(km, "_NEIGH", neigh)
    rng = np.random.default_rng(7)
    u = rng.random((4000, 2)) * 40.0
    pts = np.c_[u, 3.0 * np.sin(u[:, 0] / 5.0) * np.cos(u[:, 1] / 7.0) + 0.01 * rng.standard_normal(4000)]
    pts = pts[canonical_order(pts)]  # the fit's own order: same init draws
    C0 = cl.initial_centres(pts, 120, init, np.random.default_rng(1)) if init != "random" else \
        pts[np.sort(np.random.default_rng(1).choice(4000, 120, replace=False))]
    km = KMeans(120, init=C0, max_iter=500).fit(pts)
    lab, C, it = plain_lloyd(pts, C0, 500)
    assert km.converged_ and km.n_iter_ == it
    np.testing.assert_array_equal(km.labels_, lab)
    np.testing.assert_allclose(km.cluster_centers_, C, rtol=1e-12, atol=1e-12)


def test_kmeans_tol_stops_early_and_canonical_order_is_lexsort():
    from cloudsieve.core.knn import canonical_order

    rng = np.random.default_rng(3)
    pts = rng.random((6000, 3))
    full = KMeans(60, seed=2).fit(pts)
    early = KMeans(60, seed=2, tol=0.01).fit(pts)
    assert early.converged_ and early.n_iter_ < full.n_iter_
    # tol: stop at the first iteration where at most tol * n points changed
    again = KMeans(60, seed=2, tol=0.01, max_iter=early.n_iter_ - 1)
    with pytest.warns(ConvergenceWarning):
        again.fit(pts)
    with pytest.raises(ValueError, match=r"tol must be in \[0, 1\), got 1.5"):
        KMeans(2, tol=1.5).fit(pts)
    q = np.round(rng.random((5000, 3)) * 4)  # many ties in every column
    np.testing.assert_array_equal(canonical_order(q), np.lexsort(q.T[::-1]))


def test_kmeans_warns_at_max_iter():
    rng = np.random.default_rng(0)
    pts = rng.random((2000, 3))
    with pytest.warns(ConvergenceWarning, match=r"max_iter=1 .*n=2000, n_clusters=20"):
        km = KMeans(20, max_iter=1).fit(pts)
    assert km.n_iter_ == 1 and not km.converged_


def dense_fcm(X, C, m, tol, max_iter):
    """Textbook FCM on the full n x c membership matrix (the oracle)."""
    U_old = None
    for it in range(1, max_iter + 1):
        d = np.sqrt(((X[:, None, :] - C[None]) ** 2).sum(-1))
        U = 1.0 / ((d[:, :, None] / d[:, None, :]) ** (2 / (m - 1))).sum(2)
        if U_old is not None and np.abs(U - U_old).max() < tol:
            return U, C, it
        U_old = U
        W = U**m
        C = (W.T @ X) / W.sum(0)[:, None]
    return U, C, it


@pytest.mark.parametrize("extra", [0, 3])
def test_truncated_fcm_equals_dense_when_all_centres_kept(extra):
    rng = np.random.default_rng(4)
    pts = rng.random((400, 3))
    c = 7
    C0 = pts[rng.choice(400, c, replace=False)] + 1e-3  # off the points: the oracle divides by d
    f = FuzzyCMeans(c, n_nearest=c + extra, init=C0, tol=1e-7, max_iter=500).fit(pts)
    U, C, it = dense_fcm(pts, C0.copy(), 2.0, 1e-7, 500)
    assert f.converged_ and f.n_iter_ == it
    np.testing.assert_allclose(f.cluster_centers_, C, rtol=1e-10)
    dense = np.zeros((400, c))
    np.put_along_axis(dense, f.membership_indices_, f.memberships_, 1)
    np.testing.assert_allclose(dense, U, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(f.labels_, U.argmax(1))
    # memberships are stored nearest first
    d = np.linalg.norm(pts[:, None, :] - f.cluster_centers_[f.membership_indices_], axis=2)
    assert (np.diff(d, axis=1) >= 0).all()


def test_truncated_fcm_close_to_dense_with_few_centres_kept():
    rng = np.random.default_rng(5)
    pts, _ = blobs(rng, c=5, per=80, gap=30.0, spread=2.0)
    C0 = pts[rng.choice(len(pts), 5, replace=False)]
    f = FuzzyCMeans(5, n_nearest=5, init=C0).fit(pts)
    g = FuzzyCMeans(5, n_nearest=3, init=C0).fit(pts)
    assert same_partition(f.labels_, g.labels_)
    assert g.memberships_.shape == (len(pts), 3)
    np.testing.assert_allclose(g.memberships_.sum(1), 1.0)


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")
@pytest.mark.parametrize("est", [KMeans, FuzzyCMeans])
def test_invariant_to_order_and_units(est):
    rng = np.random.default_rng(6)
    pts = rng.random((4000, 3))
    perm = rng.permutation(len(pts))
    a = est(10, seed=1).fit(pts)
    b = est(10, seed=1).fit(pts[perm])
    c = est(10, seed=1).fit(pts * 1000.0)
    np.testing.assert_array_equal(a.labels_[perm], b.labels_)
    np.testing.assert_array_equal(a.labels_, c.labels_)
    np.testing.assert_allclose(a.cluster_centers_ * 1000.0, c.cluster_centers_, rtol=1e-9)


def test_bad_input_messages():
    with pytest.raises(InvalidParameterError, match=r"n_clusters=5 but the input has only 3 points"):
        KMeans(5).fit(np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"n_clusters=5 but the input has only 4 points"):
        FuzzyCMeans(5).fit(np.random.default_rng(0).random((4, 3)))
    with pytest.raises(InvalidPointsError, match=r"non-finite .* index 1"):
        KMeans(1).fit(np.array([[0, 0, 0], [np.inf, 0, 0]]))
    with pytest.raises(ValueError, match=r"shape \(n, d\), got shape \(2, 3, 1\)"):
        KMeans(1).fit(np.zeros((2, 3, 1)))
    with pytest.raises(ValueError, match=r"fuzzifier m must be > 1, got 1.0"):
        FuzzyCMeans(2, m=1.0).fit(np.random.default_rng(0).random((10, 3)))
    with pytest.raises(ValueError, match=r"init must be 'k-means\+\+', 'random', 'kd-split' or an array of centres, got 'x'"):
        KMeans(2, init="x").fit(np.random.default_rng(0).random((10, 3)))


def test_membership_change_equals_dense_difference():
    from cloudsieve.core.fcm import _max_change

    rng = np.random.default_rng(0)
    n, L, c = 300, 4, 9
    i0 = np.stack([rng.choice(c, L, replace=False) for _ in range(n)])
    i1 = np.stack([rng.choice(c, L, replace=False) for _ in range(n)])
    i1[:150] = i0[:150, ::-1]  # same centres, other order
    u0, u1 = rng.random((n, L)), rng.random((n, L))
    d0, d1 = np.zeros((n, c)), np.zeros((n, c))
    np.put_along_axis(d0, i0, u0, 1)
    np.put_along_axis(d1, i1, u1, 1)
    for rows in (slice(None), slice(0, 150), slice(150, None)):
        assert _max_change(i0[rows], u0[rows], i1[rows], u1[rows]) == np.abs(d1 - d0)[rows].max()


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")
def test_fcm_blocks_do_not_change_the_result(monkeypatch):
    import cloudsieve.core.fcm as fcm

    rng = np.random.default_rng(9)
    pts = rng.random((1000, 3))
    a = FuzzyCMeans(12, n_nearest=4, max_iter=40, tol=1e-4).fit(pts)
    monkeypatch.setattr(fcm, "_BLOCK", 97)
    b = FuzzyCMeans(12, n_nearest=4, max_iter=40, tol=1e-4).fit(pts)
    assert a.n_iter_ == b.n_iter_
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_allclose(a.cluster_centers_, b.cluster_centers_, rtol=1e-12)
    np.testing.assert_allclose(a.memberships_, b.memberships_, rtol=1e-10, atol=1e-14)


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")
@pytest.mark.parametrize("label_tol", [0.0, 0.01, 0.05])
def test_fcm_label_tol_stops_at_the_first_small_relabelling(monkeypatch, label_tol):
    """label_tol: FCM stops after the first update in which at most label_tol * n
    hard labels changed. Oracle: runs of 1, 2, ... updates without it, whose
    labels are compared by hand; the stopped run equals the run of that length."""
    import cloudsieve.core.fcm as fcm

    rng = np.random.default_rng(3)
    pts = rng.random((2000, 3)) * [10.0, 10.0, 1.0]
    monkeypatch.setattr(fcm, "_BLOCK", 333)  # the count spans blocks
    runs = [FuzzyCMeans(20, n_nearest=6, max_iter=t, seed=2).fit(pts) for t in range(1, 41)]
    changed = [None] + [int((runs[t].labels_ != runs[t - 1].labels_).sum()) for t in range(1, 40)]
    first = next((t for t in range(1, 40) if changed[t] <= label_tol * len(pts)), None)
    f = FuzzyCMeans(20, n_nearest=6, max_iter=40, seed=2, label_tol=label_tol).fit(pts)
    if first is None:
        assert f.n_iter_ == 40 and not f.converged_
        return
    assert f.converged_ and f.n_iter_ == first + 1
    np.testing.assert_array_equal(f.labels_, runs[first].labels_)
    np.testing.assert_array_equal(f.cluster_centers_, runs[first].cluster_centers_)


def test_fcm_label_tol_checked():
    with pytest.raises(InvalidParameterError, match=r"label_tol must be None or in \[0, 1\), got 1\.5"):
        FuzzyCMeans(2, label_tol=1.5).fit(np.random.default_rng(0).random((10, 3)))


def truncated_fcm(X, C, m, L, updates):
    """FCM over each point's L nearest centres, found by brute force at every
    update (the oracle of the k-d tree code and its bounds)."""
    for t in range(1, updates + 1):
        d2 = ((X[:, None, :] - C[None]) ** 2).sum(-1)
        idx = np.argsort(d2, axis=1, kind="stable")[:, :L]
        dl = np.take_along_axis(d2, idx, 1)
        U = 1.0 / ((dl[:, :, None] / dl[:, None, :]) ** (1 / (m - 1))).sum(2)
        if t == updates:
            break
        W = U**m
        num = np.zeros_like(C)
        for j in range(X.shape[1]):
            np.add.at(num[:, j], idx, W * X[:, j : j + 1])
        den = np.zeros(len(C))
        np.add.at(den, idx, W)
        C = num / den[:, None]
    return idx, U, C


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")
@pytest.mark.parametrize("L,c", [(3, 40), (8, 30), (8, 12), (6, 7)])
def test_truncated_fcm_equals_brute_force_nearest_centres(monkeypatch, L, c):
    """With n_nearest < n_clusters, every update uses exactly the L nearest
    centres (the bounds that skip the k-d tree never keep a stale set)."""
    import cloudsieve.core.fcm as fcm

    rng = np.random.default_rng(L * 100 + c)
    pts = rng.random((1500, 3)) * [10.0, 10.0, 2.0]
    C0 = pts[rng.choice(len(pts), c, replace=False)] + 1e-3
    monkeypatch.setattr(fcm, "_BLOCK", 400)
    f = FuzzyCMeans(c, n_nearest=L, init=C0, tol=1e-12, max_iter=25).fit(pts)
    idx, U, C = truncated_fcm(pts, C0.copy(), 2.0, L, 25)
    assert f.n_iter_ == 25
    np.testing.assert_allclose(f.cluster_centers_, C, rtol=1e-9)
    np.testing.assert_array_equal(np.sort(f.membership_indices_, axis=1), np.sort(idx, axis=1))
    np.testing.assert_array_equal(f.membership_indices_, idx)  # nearest first
    np.testing.assert_allclose(f.memberships_, U, rtol=1e-9)
    np.testing.assert_array_equal(f.labels_, idx[np.arange(len(idx)), U.argmax(1)])


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")
@pytest.mark.parametrize("est", [KMeans, FuzzyCMeans])
def test_same_result_whatever_the_thread_count(est):
    """The compiled passes run in chunks on threads: bit-identical fits for 1, 2 and 3 threads."""
    rng = np.random.default_rng(12)
    u = rng.random((60_000, 2)) * 60.0
    pts = np.c_[u, 2.0 * np.sin(u[:, 0] / 4.0) + 0.01 * rng.standard_normal(60_000)]
    kw = {"tol": 0.01} if est is KMeans else {"max_iter": 12, "label_tol": 0.01}
    fits = [est(150, seed=4, **kw).fit(pts, threads=t) for t in (1, 2, 3)]
    for f in fits[1:]:
        assert f.n_iter_ == fits[0].n_iter_ and f.converged_ == fits[0].converged_
        np.testing.assert_array_equal(f.labels_, fits[0].labels_)
        np.testing.assert_array_equal(f.cluster_centers_, fits[0].cluster_centers_)
        if est is FuzzyCMeans:
            np.testing.assert_array_equal(f.memberships_, fits[0].memberships_)
            np.testing.assert_array_equal(f.membership_indices_, fits[0].membership_indices_)


def kmeanspp_oracle(X, c, rng, B=64):
    """k-means++ as numpy code, one draw at a time (the code the compiled steps replaced)."""
    n = len(X)
    s = min(n, max(1000, 4 * c))
    S = X if s >= n else X[np.sort(rng.choice(n, s, replace=False))]
    S = S[np.argsort(S[:, 0], kind="stable")]
    s, p = S.shape
    nb = -(-s // B)
    x = S[:, 0].copy()
    d2 = np.zeros(nb * B)
    chosen = np.empty(c, dtype=np.int64)
    chosen[0] = rng.integers(s)
    d2[:s] = sum((S[:, j] - S[chosen[0], j]) ** 2 for j in range(p))
    bsum = d2.reshape(nb, B).sum(axis=1)
    bmax = d2.reshape(nb, B).max(axis=1)
    for k in range(1, c):
        if bsum.sum() > 0:
            cum = np.cumsum(bsum)
            r = rng.random() * cum[-1]
            b = min(int(np.searchsorted(cum, r, side="right")), nb - 1)
            r -= cum[b - 1] if b else 0.0
            within = np.cumsum(d2[b * B : (b + 1) * B])
            nxt = b * B + min(int(np.searchsorted(within, r, side="right")), B - 1)
            while nxt >= s or d2[nxt] == 0:
                nxt -= 1
        else:
            nxt = int(rng.integers(s))
        chosen[k] = nxt
        reach = np.sqrt(bmax.max())
        lo = int(np.searchsorted(x, x[nxt] - reach, side="left"))
        hi = int(np.searchsorted(x, x[nxt] + reach, side="right"))
        lo, hi = (lo // B) * B, min(-(-hi // B) * B, s)
        dn = sum((S[lo:hi, j] - S[nxt, j]) ** 2 for j in range(p))
        np.minimum(d2[lo:hi], dn, out=d2[lo:hi])
        blo, bhi = lo // B, -(-hi // B)
        part = d2[blo * B : bhi * B].reshape(-1, B)
        bsum[blo:bhi] = part.sum(axis=1)
        bmax[blo:bhi] = part.max(axis=1)
    return S[chosen]


@pytest.mark.parametrize("case", ["surface", "few distinct points"])
def test_kmeanspp_equals_the_numpy_oracle(case):
    """Same centres bit for bit, and the generator left in the same state (the
    compiled steps draw their uniforms ahead); with few distinct points the
    draws run out of positive D^2 and fall back to rng.integers."""
    import cloudsieve.core.cluster as cl

    rng = np.random.default_rng(8)
    if case == "surface":
        u = rng.random((30_000, 2)) * 20.0
        X, c = np.c_[u, np.sin(u[:, 0]) + 0.01 * rng.standard_normal(30_000)], 300
    else:
        X, c = np.repeat(rng.random((50, 3)), 20, axis=0), 80
    X = X[np.lexsort(X.T[::-1])]
    r1, r2 = np.random.default_rng(3), np.random.default_rng(3)
    got = cl.initial_centres(X, c, "k-means++", r1)
    want = kmeanspp_oracle(X, c, r2)
    np.testing.assert_array_equal(got, want)
    assert r1.random() == r2.random()


@pytest.mark.parametrize("m", [1.5, 3.0])
def test_fcm_with_another_fuzzifier_equals_dense(m):
    rng = np.random.default_rng(13)
    pts = rng.random((500, 3))
    c = 6
    C0 = pts[rng.choice(500, c, replace=False)] + 1e-3
    f = FuzzyCMeans(c, m=m, n_nearest=c, init=C0, tol=1e-6, max_iter=1000).fit(pts)
    U, C, it = dense_fcm(pts, C0.copy(), m, 1e-6, 1000)
    assert f.converged_ and f.n_iter_ == it
    np.testing.assert_allclose(f.cluster_centers_, C, rtol=1e-10)
    dense = np.zeros((500, c))
    np.put_along_axis(dense, f.membership_indices_, f.memberships_, 1)
    np.testing.assert_allclose(dense, U, rtol=1e-9, atol=1e-12)
