"""The compiled kernels against scipy's cKDTree and the brute-force entropy oracle."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from test_core_entropy import oracle

from cloudsieve.core.kernels.entropy import entropy_gain, entropy_weights, reverse_sums
from cloudsieve.core.kernels.knn import knn_unchecked
from cloudsieve.core.kernels.order import stable_argsort
from cloudsieve.core.knn import canonical_order, group, knn_clusters
from cloudsieve.core.scored_knn import knn_scored_clusters
from cloudsieve.errors import InvalidParameterError



def knn_in_clusters(points, indptr, k, *, query=None, threads=1):
    """The k nearest inside clusters by the kernel: 1- and 2-D points padded with zero columns, k one per
    cluster or one for all (the checks of the public entries are theirs: the kernel takes checked input)."""
    P = np.asarray(points, dtype=np.float64)
    P = np.ascontiguousarray(np.column_stack([P, np.zeros((len(P), 3 - P.shape[1]))]))
    ip = np.asarray(indptr, dtype=np.int64)
    kc = np.broadcast_to(np.asarray(k, dtype=np.int64), (len(ip) - 1,)).copy()
    q = np.ones(len(P), dtype=bool) if query is None else np.asarray(query)
    return knn_unchecked(P, ip, kc, q, threads)


KINDS = ["random", "grid", "duplicates", "collinear", "planar"]


def _cloud(rng, kind, m, dim=3):
    """m points of one kind: ties (integer grids), copies, a line, a plane."""
    if kind == "random":
        return rng.random((m, dim)) * rng.uniform(0.01, 100)
    if kind == "grid":  # many exactly equal distances
        return rng.integers(0, max(2, round(m ** (1 / dim)) + 2), (m, dim)).astype(float)
    if kind == "duplicates":
        p = rng.random((m, dim))
        p[rng.integers(0, m, m // 3)] = p[rng.integers(0, m, m // 3)]
        return p
    if kind == "collinear":  # integer steps along a line: ties on both sides
        p = np.zeros((m, dim))
        p[:, 0] = rng.integers(0, 2 * m, m)
        return p @ np.linalg.qr(rng.standard_normal((dim, dim)))[0] if dim > 1 and rng.random() < 0.5 else p
    p = np.zeros((m, dim))  # planar, on a tilted lattice half of the time
    p[:, : min(2, dim)] = rng.integers(0, round(np.sqrt(m)) + 2, (m, min(2, dim)))
    return p + 1000.0 if rng.random() < 0.5 else p * 0.1


def _reference(P, kq):
    """The kq nearest other points of each row: the smallest (squared distance, row) pairs,
    squared distances summed as cKDTree sums them."""
    m = len(P)
    diff = P[:, None, :] - P[None, :, :]
    d2 = diff[..., 0] * diff[..., 0]
    for j in range(1, P.shape[1]):
        d2 = d2 + diff[..., j] * diff[..., j]
    np.fill_diagonal(d2, np.inf)
    kk = min(kq, m - 1)
    idx = np.array([np.lexsort((np.arange(m), row))[:kk] for row in d2], dtype=np.int64).reshape(m, kk)
    return np.sqrt(np.take_along_axis(d2, idx, axis=1)), idx


def _clusters(seed, n_clusters=6, dim=3):
    rng = np.random.default_rng(seed)
    sizes = rng.integers(5, 601, n_clusters)
    parts = [_cloud(rng, KINDS[(seed + j) % len(KINDS)], int(m), dim) + 1e4 * j for j, m in enumerate(sizes)]
    return np.concatenate(parts), np.r_[0, np.cumsum(sizes)], rng.integers(4, 31, n_clusters)


@pytest.mark.parametrize("seed", range(10))
def test_matches_ckdtree_and_reference(seed):
    P, indptr, k = _clusters(seed)
    d, i = knn_in_clusters(P, indptr, k, threads=2)
    assert d.shape == i.shape == (len(P), k.max())
    for j in range(len(k)):
        a, b = indptr[j], indptr[j + 1]
        C = P[a:b]
        kk = min(int(k[j]), len(C) - 1)
        dk = cKDTree(C).query(C, k=kk + 1)[0][:, 1:]
        # the same distances as cKDTree, bit for bit (its first column is a copy at 0 or the point)
        np.testing.assert_array_equal(d[a:b, :kk], dk)
        rd, ri = _reference(C, kk)
        np.testing.assert_array_equal(d[a:b, :kk], rd)
        np.testing.assert_array_equal(i[a:b, :kk], ri + a)  # ties: the lower row first
        assert np.isinf(d[a:b, kk:]).all() and (i[a:b, kk:] == -1).all()


@pytest.mark.parametrize("dim", [1, 2])
def test_fewer_dimensions(dim):
    P, indptr, k = _clusters(3, dim=dim)
    d, i = knn_in_clusters(P, indptr, k)
    for j in range(len(k)):
        a, b = indptr[j], indptr[j + 1]
        kk = min(int(k[j]), b - a - 1)
        np.testing.assert_array_equal(d[a:b, :kk], cKDTree(P[a:b]).query(P[a:b], k=kk + 1)[0][:, 1:])
        np.testing.assert_array_equal(i[a:b, :kk], _reference(P[a:b], kk)[1] + a)


def test_one_tree_with_a_cluster_coordinate_gives_the_same_bits():
    # entropy's one k-d tree over all clusters adds the cluster id times a gap as a 4th
    # coordinate: inside a cluster it adds exactly 0.0, so its distances are these
    rng = np.random.default_rng(8)
    P = np.concatenate([_cloud(rng, kind, 400) * 3.7 + 50 for kind in KINDS])
    lab = np.repeat(np.arange(5), 400)
    X = np.column_stack([P, lab * (2 * np.ptp(P, axis=0).max() * np.sqrt(3) + 1)])
    d4 = cKDTree(X, leafsize=32, balanced_tree=False, compact_nodes=False).query(X, k=22)[0][:, 1:]
    d, _ = knn_in_clusters(P, np.arange(0, 2001, 400), 21)
    np.testing.assert_array_equal(d, d4)


def test_large_cluster_and_thread_count_do_not_change_the_result():
    rng = np.random.default_rng(1)
    P = np.concatenate([rng.random((20000, 3)), rng.integers(0, 30, (3000, 3)) * 0.5])
    indptr = [0, 20000, 23000]
    d1, i1 = knn_in_clusters(P, indptr, [25, 12], threads=1)
    d3, i3 = knn_in_clusters(P, indptr, [25, 12], threads=3)
    np.testing.assert_array_equal(d1, d3)
    np.testing.assert_array_equal(i1, i3)
    np.testing.assert_array_equal(d1[:20000], cKDTree(P[:20000]).query(P[:20000], k=26)[0][:, 1:])
    np.testing.assert_array_equal(d1[20000:, :12], cKDTree(P[20000:]).query(P[20000:], k=13)[0][:, 1:])


def test_query_subset_small_clusters_and_padding():
    rng = np.random.default_rng(2)
    P = rng.random((60, 3))
    indptr = [0, 0, 1, 3, 60]  # an empty cluster, one point, two points, 57
    q = rng.random(60) < 0.5
    d, i = knn_in_clusters(P, indptr, [4, 4, 4, 6], query=q)
    full_d, full_i = knn_in_clusters(P, indptr, [4, 4, 4, 6])
    np.testing.assert_array_equal(d[q], full_d[q])
    np.testing.assert_array_equal(i[q], full_i[q])
    assert np.isinf(d[~q]).all() and (i[~q] == -1).all()
    assert np.isinf(full_d[0]).all() and (full_i[0] == -1).all()  # alone in its cluster
    assert full_i[1].tolist() == [2, -1, -1, -1, -1, -1] and full_i[2, 0] == 1
    assert full_d[3:, :6].max() < np.inf
    d0, i0 = knn_in_clusters(P, [0, 60], 0)
    assert d0.shape == i0.shape == (60, 0)


def _numpy_gain(cl, c, rk, rk1, nbr, kr, dim, rows, n):
    """The numpy formulas of entropy.score_points (its _weights, bincounts and _change)."""
    lr, lr1 = np.log(rk), np.log(rk1)
    shift = np.full(c, np.inf)
    np.minimum.at(shift, cl, lr)
    lw, lw1 = -dim * (lr - shift[cl]), -dim * (lr1 - shift[cl])
    w, w1 = np.exp(lw), np.exp(lw1)
    W = np.bincount(cl, weights=w, minlength=c)
    A = np.bincount(cl, weights=w * lw, minlength=c)
    L = A / W
    gw, gw1 = w * (lw - L[cl]), w1 * (lw1 - L[cl])
    dw, dg = w1 - w, gw1 - gw
    acc_w, acc_g = np.zeros(n + 1), np.zeros(n + 1)
    for k in np.unique(kr):  # one bincount per k, as score_points groups its queries
        at = np.flatnonzero(kr == k)
        tgt = nbr[at, :k].ravel()
        acc_w += np.bincount(tgt, weights=np.repeat(dw[at], k), minlength=n + 1)
        acc_g += np.bincount(tgt, weights=np.repeat(dg[at], k), minlength=n + 1)
    dW, dG, Wc = acc_w[rows] - w, acc_g[rows] - gw, W[cl]
    return np.log1p(dW / Wc) - dG / (Wc + dW)


def _scored(P, indptr, k0=1.0, k_min=4):
    """The scoring inputs of clusters of distinct points: k per cluster, the k + 1 nearest."""
    m = np.diff(indptr)
    k = np.maximum(np.floor(k0 * np.sqrt(m) + 0.5).astype(np.int64), k_min)
    d, nbr = knn_in_clusters(P, indptr, k + 1)
    cl = np.repeat(np.arange(len(m)), m)
    kr = k[cl]
    rows = np.arange(len(P))
    return cl, d[rows, kr - 1], d[rows, kr], nbr, kr


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("lattice", [False, True], ids=["random", "ties"])
def test_entropy_gain_matches_oracle_and_numpy_bits(dim, lattice):
    rng = np.random.default_rng(20 + dim + lattice)
    parts = []
    for m in rng.integers(20, 301, 4):
        if lattice:  # distinct integer points: ties, no copies
            side = int(np.ceil(m ** (1 / dim))) + 3
            cells = rng.choice(side**dim, size=m, replace=False)
            parts.append(np.stack(np.unravel_index(cells, (side,) * dim), axis=1).astype(float))
        else:
            parts.append(rng.random((m, dim)) * rng.uniform(0.5, 5))
    P = np.concatenate([p + 100.0 * j for j, p in enumerate(parts)])
    indptr = np.r_[0, np.cumsum([len(p) for p in parts])]
    cl, rk, rk1, nbr, kr = _scored(P, indptr)
    n, c, rows = len(P), len(parts), np.arange(len(P))
    gain = entropy_gain(rows, cl, c, rk, rk1, nbr, kr, dim, n)
    np.testing.assert_array_equal(gain, _numpy_gain(cl, c, rk, rk1, nbr, kr, dim, rows, n))
    for j in range(c):
        a, b = indptr[j], indptr[j + 1]
        np.testing.assert_allclose(np.abs(gain[a:b]), oracle(P[a:b], dim=dim), rtol=1e-9, atol=1e-15)


def test_entropy_weights_and_reverse_sums():
    rng = np.random.default_rng(4)
    P = rng.random((500, 3))
    indptr = np.array([0, 180, 500])
    cl, rk, rk1, nbr, kr = _scored(P, indptr)
    w, gw, Wc, dw, dg = entropy_weights(cl, 2, rk, rk1, 3)
    assert w.max() == 1.0 and np.isclose(Wc[0], w[:180].sum())
    # only targets in the same cluster count: a mask that moves row 7 to cluster 1 drops it as a target
    tcl = cl.copy()
    tcl[7] = 1
    acc_w, _ = reverse_sums(nbr, kr, dw, dg, 500, tcl, cl)
    full_w, _ = reverse_sums(nbr, kr, dw, dg, 500)
    assert acc_w[7] == 0.0 and full_w[7] != 0.0
    np.testing.assert_array_equal(np.delete(acc_w, 7), np.delete(full_w, 7))
    with pytest.raises(InvalidParameterError, match=r"M = 500 rows and K >= max\(kr\), got shape \(500, 3\)"):
        reverse_sums(nbr[:, :3], kr, dw, dg, 500)


def _morton_reference(pts, bits):
    """The Z-order codes of the numpy code grouped_order replaced (three coordinates at most)."""
    q = min(pts.shape[1], 3)
    code = np.zeros(len(pts), dtype=np.uint64)
    lo = pts[:, :q].min(axis=0)
    span = float((pts[:, :q].max(axis=0) - lo).max())
    if not (np.isfinite(span) and span > 0):
        return code
    scale = ((1 << bits) - 1) / span
    for j in range(q):
        x = ((pts[:, j] - lo[j]) * scale).astype(np.uint64)
        for s, mask in [(32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)]:
            x |= x << np.uint64(s)
            x &= np.uint64(mask)
        code |= x << np.uint64(j)
    return code


@pytest.mark.parametrize("seed", range(6))
def test_grouped_order_is_the_stable_argsort_of_the_morton_keys(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    dim = int(rng.integers(1, 6))
    pts = _cloud(rng, KINDS[seed % len(KINDS)], n, dim)
    if seed == 5:
        pts[:] = 1.5  # one point repeated: every code 0
    lab = rng.integers(-3, int(rng.integers(1, 60)), n)
    inv, order, sizes = group(pts, lab)
    c = len(sizes)
    bits = min(21, (63 - max(1, (c - 1).bit_length())) // 3)
    key = _morton_reference(pts, bits) | (inv.astype(np.uint64) << np.uint64(3 * bits))
    np.testing.assert_array_equal(order, np.argsort(key, kind="stable"))
    np.testing.assert_array_equal(sizes, np.bincount(inv))


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("large", [False, True])
def test_scored_lists_match_knn_clusters(dim, kind, large):
    """knn_scored_clusters: the distances and lists of knn_clusters, per cluster, copies included; large:
    clusters above 2,048 points (their copies are looked for before the k-NN), one with a pile of 700
    copies of one point, one with a few copies, one with none."""
    rng = np.random.default_rng(dim * 10 + len(kind))
    n = 9000 if large else 2500
    pts = _cloud(rng, kind, n, dim)
    pts[rng.integers(0, n, 40)] = pts[rng.integers(0, n, 40)]  # copies in some clusters
    lab = rng.integers(0, 3 if large else 14, n)
    lab[:9] = 99  # a small cluster
    if large:
        pile = np.flatnonzero(lab == 0)[:700]
        pts[pile] = pts[pile[0]]
        two = np.flatnonzero(lab == 2)
        pts[two] = _cloud(rng, kind, len(two), dim) + 5.0  # no copies
    inv, order, sizes = group(pts, lab)
    indptr = np.r_[0, np.cumsum(sizes)]
    g, ginv = pts[order], inv[order]
    for threads in (1, 3):
        rk, rk1, kcl, koff, scored, nb, dup = knn_scored_clusters(pts, order, indptr, 1.0, 4, threads)
        groups, dup0 = knn_clusters(g, ginv, sizes, 1.0, 4, threads)
        np.testing.assert_array_equal(dup, dup0)
        assert scored.sum() == sum(len(grp[1]) for grp in groups)
        for k, sc, a, b, nbx in groups:
            cl = ginv[sc]
            assert (kcl[cl] == k).all() and scored[sc].all()
            np.testing.assert_array_equal(rk[sc], a)
            np.testing.assert_array_equal(rk1[sc], b)
            at = koff[cl] + (sc - indptr[cl]) * k
            np.testing.assert_array_equal(nb[at[:, None] + np.arange(k)], nbx[:, :k])


@pytest.mark.parametrize("seed", range(4))
def test_stable_argsort_and_canonical_order(seed):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(5000) * 10.0 ** rng.integers(-300, 300)
    x[rng.integers(0, 5000, 800)] = x[rng.integers(0, 5000, 800)]  # ties
    x[:50] = np.r_[0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324][rng.integers(0, 6, 50)]
    np.testing.assert_array_equal(stable_argsort(x), np.argsort(x, kind="stable"))
    X = np.round(rng.random((4000, 3)) * 5) * np.where(rng.random((4000, 3)) < 0.5, -1.0, 1.0)  # -0.0 and 0.0
    X[::9] = X[0]
    np.testing.assert_array_equal(canonical_order(X), np.lexsort(X.T[::-1]))
    np.testing.assert_array_equal(canonical_order(X.astype(np.float32)), np.lexsort(X.T[::-1]))
