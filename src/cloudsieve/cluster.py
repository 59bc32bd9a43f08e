"""K-means and fuzzy C-means into many small clusters (DESIGN.md stage 3).

Both estimators follow scikit-learn's conventions: parameters in ``__init__``,
work in ``fit``, fitted state with a trailing underscore, one ``seed``, and a
:class:`ConvergenceWarning` when ``max_iter`` runs out.

Cost per iteration is O(n log c), not O(n c): nearest centres come from a
k-d tree over the centres (scipy's ``cKDTree``, queried on all cores), and
K-means skips the points whose assignment provably cannot change (Hamerly's
bounds: distance to the own centre vs. half the distance to the nearest other
centre and a lower bound on the second nearest). Fuzzy C-means keeps each
point's memberships for its ``n_nearest`` nearest centres only (all others are
zero); with ``n_nearest >= n_clusters`` this is exactly the textbook (dense)
FCM.

Determinism: the points are put in a canonical order (lexicographic by
coordinates) before any seeded step, so results do not depend on the input
order; the only randomness is ``np.random.default_rng(seed)``.

``init="k-means++"`` (default) seeds with k-means++ (D^2 sampling) on a uniform
subsample of ``max(1000, 4 * n_clusters)`` points (all points when fewer),
which keeps the seeding O(c^2) instead of O(n c); ``init="random"`` reproduces
the paper: K-means starts from ``n_clusters`` distinct random points of X, FCM
from random memberships (dense, computed in blocks: O(n c) once). An array of
shape (n_clusters, p) gives the initial centres.
"""

from __future__ import annotations

import logging
import os
import warnings

import numpy as np
from scipy.spatial import cKDTree

from .entropy import _check_points
from .errors import InvalidParameterError

__all__ = ["KMeans", "FuzzyCMeans", "ConvergenceWarning"]

logger = logging.getLogger(__name__)


class ConvergenceWarning(UserWarning):
    """An iterative fit stopped at max_iter before its convergence test held."""


def _canonical_order(X: np.ndarray) -> np.ndarray:
    """Lexicographic order of the rows (first column first): input order never matters."""
    return np.lexsort(X.T[::-1])


def _tree(C: np.ndarray) -> cKDTree:
    return cKDTree(C, balanced_tree=False, compact_nodes=False)


def _kmeanspp(X: np.ndarray, c: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding (one trial per centre) on a uniform subsample of X."""
    n = len(X)
    s = min(n, max(1000, 4 * c))
    S = X if s == n else X[np.sort(rng.choice(n, s, replace=False))]
    chosen = np.empty(c, dtype=np.int64)
    chosen[0] = rng.integers(s)
    d2 = ((S - S[chosen[0]]) ** 2).sum(axis=1)
    for j in range(1, c):
        cum = np.cumsum(d2)
        total = cum[-1]
        if total > 0:
            nxt = int(np.searchsorted(cum, rng.random() * total, side="right"))
            nxt = min(nxt, s - 1)
        else:  # every remaining point coincides with a centre
            nxt = int(rng.integers(s))
        chosen[j] = nxt
        np.minimum(d2, ((S - S[nxt]) ** 2).sum(axis=1), out=d2)
    return S[chosen].copy()


def _check_fit_args(X, n_clusters: int, max_iter: int, init):
    pts = _check_points(X)
    n = len(pts)
    if int(n_clusters) != n_clusters or n_clusters < 1:
        raise InvalidParameterError(f"n_clusters must be an integer >= 1, got {n_clusters!r}")
    if n < n_clusters:
        raise InvalidParameterError(f"n_clusters={n_clusters} but the input has only {n} points (need n >= n_clusters)")
    if int(max_iter) != max_iter or max_iter < 1:
        raise InvalidParameterError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    if isinstance(init, str):
        if init not in ("k-means++", "random"):
            raise InvalidParameterError(f"init must be 'k-means++', 'random' or an array of centres, got {init!r}")
    else:
        a = np.asarray(init, dtype=np.float64)
        if a.shape != (n_clusters, pts.shape[1]):
            raise InvalidParameterError(
                f"init centres must have shape ({n_clusters}, {pts.shape[1]}), got shape {a.shape}")
    return pts


class KMeans:
    """Lloyd's K-means with k-d tree assignment and Hamerly's bounds.

    Stops when no point changes cluster (the paper) or after ``max_iter``
    iterations (then a :class:`ConvergenceWarning`). An empty cluster keeps its
    previous centre.

    Parameters
    ----------
    n_clusters : int
    init : {"k-means++", "random"} or ndarray of shape (n_clusters, p)
    max_iter : int
    seed : int

    Attributes
    ----------
    cluster_centers_ : ndarray of shape (n_clusters, p)
    labels_ : ndarray of shape (n,), int64
    n_iter_ : int
        Centre updates done.
    converged_ : bool

    Examples
    --------
    >>> import numpy as np
    >>> X = np.r_[np.zeros((5, 3)), np.ones((5, 3))] + np.arange(10)[:, None] * 1e-3
    >>> KMeans(2, seed=0).fit(X).labels_.tolist() in ([0] * 5 + [1] * 5, [1] * 5 + [0] * 5)
    True
    """

    def __init__(self, n_clusters: int, *, init="k-means++", max_iter: int = 300, seed: int = 0):
        self.n_clusters = n_clusters
        self.init = init
        self.max_iter = max_iter
        self.seed = seed

    def fit(self, points, workers: int | None = None) -> KMeans:
        """Cluster ``points`` (array of shape (n, p)); returns self."""
        X = _check_fit_args(points, self.n_clusters, self.max_iter, self.init)
        c = int(self.n_clusters)
        workers = int(workers or os.cpu_count() or 1)
        order = _canonical_order(X)
        Xs = X[order]
        rng = np.random.default_rng(self.seed)
        if isinstance(self.init, str) and self.init == "random":
            C = Xs[np.sort(rng.choice(len(Xs), c, replace=False))].copy()
        elif isinstance(self.init, str):
            C = _kmeanspp(Xs, c, rng)
        else:
            C = np.array(self.init, dtype=np.float64)
        labels, C, n_iter, conv = _lloyd(Xs, C, self.max_iter, workers)
        if not conv:
            warnings.warn(
                f"KMeans stopped at max_iter={self.max_iter} with points still changing cluster "
                f"(n={len(X)}, n_clusters={c})", ConvergenceWarning, stacklevel=2)
        out = np.empty(len(X), dtype=np.int64)
        out[order] = labels
        self.labels_ = out
        self.cluster_centers_ = C
        self.n_iter_ = n_iter
        self.converged_ = conv
        return self

    def fit_predict(self, points) -> np.ndarray:
        return self.fit(points).labels_


def _sums(Xs, a, c):
    cnt = np.bincount(a, minlength=c).astype(np.float64)
    S = np.stack([np.bincount(a, weights=Xs[:, j], minlength=c) for j in range(Xs.shape[1])], axis=1)
    return S, cnt


def _lloyd(Xs, C, max_iter, workers):
    n, p = Xs.shape
    c = len(C)
    if c == 1:
        return np.zeros(n, dtype=np.int64), Xs.mean(axis=0, keepdims=True), 1, True
    d, i = _tree(C).query(Xs, k=2, workers=workers)
    a = i[:, 0].astype(np.int64)
    u = d[:, 0].copy()
    low = d[:, 1].copy()
    S, cnt = _sums(Xs, a, c)
    conv = False
    it = 0
    for it in range(1, max_iter + 1):
        nonempty = cnt > 0
        Cn = C.copy()
        Cn[nonempty] = S[nonempty] / cnt[nonempty, None]
        delta = np.sqrt(((Cn - C) ** 2).sum(axis=1))
        C = Cn
        moved_c = delta > 0
        if moved_c.any():
            u += delta[a]
            low -= delta.max()
        tree = _tree(C)
        half = 0.5 * tree.query(C, k=2)[0][:, 1]
        act = np.flatnonzero(u > low)
        if len(act):
            aa = a[act]
            act = act[u[act] > half[aa]]
        if len(act):
            u[act] = np.sqrt(((Xs[act] - C[a[act]]) ** 2).sum(axis=1))
            z = np.maximum(low[act], half[a[act]])
            act = act[u[act] > z]
        changed = np.zeros(0, dtype=np.int64)
        if len(act):
            w = workers if len(act) >= 20_000 else 1  # threads cost more than they save on small queries
            d, i = tree.query(Xs[act], k=2, workers=w)
            na = i[:, 0].astype(np.int64)
            moved = na != a[act]
            changed = act[moved]
            if len(changed):
                old = a[changed]
                new = na[moved]
                for j in range(p):
                    S[:, j] -= np.bincount(old, weights=Xs[changed, j], minlength=c)
                    S[:, j] += np.bincount(new, weights=Xs[changed, j], minlength=c)
                cnt -= np.bincount(old, minlength=c)
                cnt += np.bincount(new, minlength=c)
            a[act] = na
            u[act] = d[:, 0]
            low[act] = d[:, 1]
        if len(changed) == 0:
            conv = True
            break
        if it % 20 == 0:  # refresh the running sums (no drift from +/- updates)
            S, cnt = _sums(Xs, a, c)
    if conv:
        # centres are the means of the final clusters
        S, cnt = _sums(Xs, a, c)
        ne = cnt > 0
        C = C.copy()
        C[ne] = S[ne] / cnt[ne, None]
    return a, C, it, conv


class FuzzyCMeans:
    """Fuzzy C-means with memberships over the ``n_nearest`` nearest centres.

    u_ij = 1 / sum_l (d_ij / d_il)^(2/(m-1)) over the point's L = min(n_nearest,
    n_clusters) nearest centres (0 for the others), centres the u^m-weighted
    means; stops when the largest change of a membership between two
    iterations is below ``tol`` (compared as full n x c matrices) or after
    ``max_iter`` membership updates (then a :class:`ConvergenceWarning`).
    Hard label: the centre of largest membership (the nearest for a tie).

    Parameters
    ----------
    n_clusters : int
    m : float
        Fuzzifier, > 1 (2 in the paper).
    tol : float
    n_nearest : int
    init : {"k-means++", "random"} or ndarray of shape (n_clusters, p)
    max_iter : int
    seed : int

    Attributes
    ----------
    cluster_centers_ : ndarray of shape (n_clusters, p)
        The centres the final memberships were computed from.
    labels_ : ndarray of shape (n,), int64
    memberships_ : ndarray of shape (n, L), float64
        Memberships to the L nearest centres, nearest first.
    membership_indices_ : ndarray of shape (n, L), int64
        The centres those memberships refer to.
    n_iter_ : int
        Membership updates done.
    converged_ : bool
    """

    def __init__(self, n_clusters: int, *, m: float = 2.0, tol: float = 1e-5, n_nearest: int = 8,
                 init="k-means++", max_iter: int = 300, seed: int = 0):
        self.n_clusters = n_clusters
        self.m = m
        self.tol = tol
        self.n_nearest = n_nearest
        self.init = init
        self.max_iter = max_iter
        self.seed = seed

    def fit(self, points, workers: int | None = None) -> FuzzyCMeans:
        """Cluster ``points`` (array of shape (n, p)); returns self."""
        X = _check_fit_args(points, self.n_clusters, self.max_iter, self.init)
        if not (np.isfinite(self.m) and self.m > 1):
            raise InvalidParameterError(f"fuzzifier m must be > 1, got {self.m!r}")
        if not (self.tol > 0):
            raise InvalidParameterError(f"tol must be > 0, got {self.tol!r}")
        if int(self.n_nearest) != self.n_nearest or self.n_nearest < 1:
            raise InvalidParameterError(f"n_nearest must be an integer >= 1, got {self.n_nearest!r}")
        c = int(self.n_clusters)
        L = min(int(self.n_nearest), c)
        workers = int(workers or os.cpu_count() or 1)
        order = _canonical_order(X)
        Xs = X[order]
        rng = np.random.default_rng(self.seed)
        if isinstance(self.init, str) and self.init == "random":
            C = _random_membership_centres(Xs, c, self.m, rng)
        elif isinstance(self.init, str):
            C = _kmeanspp(Xs, c, rng)
        else:
            C = np.array(self.init, dtype=np.float64)
        idx, U, C, n_iter, conv = _fcm(Xs, C, L, float(self.m), float(self.tol), int(self.max_iter), workers)
        if not conv:
            warnings.warn(
                f"FuzzyCMeans stopped at max_iter={self.max_iter} with membership change >= tol={self.tol} "
                f"(n={len(X)}, n_clusters={c})", ConvergenceWarning, stacklevel=2)
        best = np.argmax(U, axis=1)
        lab = idx[np.arange(len(idx)), best]
        out = np.empty(len(X), dtype=np.int64)
        out[order] = lab
        mem = np.empty_like(U)
        mem[order] = U
        mi = np.empty_like(idx)
        mi[order] = idx
        self.labels_ = out
        self.memberships_ = mem
        self.membership_indices_ = mi
        self.cluster_centers_ = C
        self.n_iter_ = n_iter
        self.converged_ = conv
        return self

    def fit_predict(self, points) -> np.ndarray:
        return self.fit(points).labels_


def _random_membership_centres(Xs, c, m, rng, block=None):
    """Centres from dense random memberships (rows normalised), in blocks of points."""
    n, p = Xs.shape
    block = block or max(1, 4_000_000 // c)
    num = np.zeros((c, p))
    den = np.zeros(c)
    for s in range(0, n, block):
        U = rng.random((min(block, n - s), c))
        U /= U.sum(axis=1, keepdims=True)
        Um = U**m
        num += Um.T @ Xs[s : s + block]
        den += Um.sum(axis=0)
    return num / den[:, None]


def _max_change(idx0, U0, idx1, U1, c=None):
    """max |U1 - U0| over the full n x c matrices, from their kept entries.

    Rows hold the memberships to centres idx (n, L), in any order; an entry
    absent from one side is 0 there.
    """
    if len(idx0) == 0:
        return 0.0
    s0 = np.argsort(idx0, axis=1)
    s1 = np.argsort(idx1, axis=1)
    i0 = np.take_along_axis(idx0, s0, 1)
    i1 = np.take_along_axis(idx1, s1, 1)
    same = (i0 == i1).all(axis=1)
    best = 0.0
    if same.any():  # the usual case: same centres, maybe in another order
        best = float(np.abs(np.take_along_axis(U1[same], s1[same], 1) - np.take_along_axis(U0[same], s0[same], 1)).max())
    if same.all():
        return best
    idx0, U0, idx1, U1 = idx0[~same], U0[~same], idx1[~same], U1[~same]
    eq = idx1[:, :, None] == idx0[:, None, :]  # (n, L1, L0)
    matched0 = (eq * U0[:, None, :]).sum(axis=2)  # U0 at the new entries
    best = max(best, float(np.abs(U1 - matched0).max()))
    gone = ~eq.any(axis=1)  # old entries absent from the new set
    if gone.any():
        best = max(best, float(U0[gone].max()))
    return best


_BLOCK = 1 << 17  # rows per block in FCM: bounds the temporaries to O(block * L)


def _dist_to(Xs, C, idx):
    diff = Xs[:, None, :] - C[idx]
    return np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))


def _fcm(Xs, C, L, m, tol, max_iter, workers):
    """FCM iterations, in blocks of points (memory O(n L) for the memberships
    plus O(block L) temporaries). The L nearest centres of a point are
    re-queried only when the centres moved enough to possibly change that set:
    with g the gap between its (L+1)-th and L-th distances at the last query and
    D the sum of the largest centre moves since, the set is unchanged while
    2 D < g; otherwise distances to the same L centres are recomputed directly."""
    n, p = Xs.shape
    c = len(C)
    extra = L < c
    idx = np.zeros((n, L), dtype=np.int64)
    U = np.zeros((n, L))
    gap = np.full(n, np.inf)
    drift = np.zeros(n)
    have = False
    conv = False
    it = 0
    for it in range(1, max_iter + 1):
        tree = None
        ch = 0.0
        num = np.zeros((c, p))
        den = np.zeros(c)
        for s in range(0, n, _BLOCK):
            e = min(n, s + _BLOCK)
            if not have:
                redo = np.arange(e - s)
            elif extra:
                redo = np.flatnonzero(2.0 * drift[s:e] >= gap[s:e])
            else:
                redo = np.zeros(0, dtype=np.int64)
            new_idx = idx[s:e].copy()
            if len(redo):
                if tree is None:
                    tree = _tree(C)
                w = workers if len(redo) >= 20_000 else 1
                d, i = tree.query(Xs[s + redo], k=L + 1 if extra else L, workers=w)
                if d.ndim == 1:
                    d, i = d[:, None], i[:, None]
                if extra:
                    gap[s + redo] = d[:, L] - d[:, L - 1]
                drift[s + redo] = 0.0
                new_idx[redo] = i[:, :L]
            Ub = _memberships_any(_dist_to(Xs[s:e], C, new_idx), m)
            if have:
                if len(redo):
                    ch = max(ch, _max_change(idx[s:e][redo], U[s:e][redo], new_idx[redo], Ub[redo]))
                    rest = np.ones(e - s, dtype=bool)
                    rest[redo] = False
                    if rest.any():
                        ch = max(ch, float(np.abs(Ub[rest] - U[s:e][rest]).max()))
                else:
                    ch = max(ch, float(np.abs(Ub - U[s:e]).max()))
            idx[s:e] = new_idx
            U[s:e] = Ub
            wm = (Ub**m).ravel()
            flat = new_idx.ravel()
            den += np.bincount(flat, weights=wm, minlength=c)
            for j in range(p):
                num[:, j] += np.bincount(flat, weights=(Ub**m * Xs[s:e, j : j + 1]).ravel(), minlength=c)
        if have and ch < tol:
            conv = True
            break
        have = True
        if it == max_iter:
            break
        Cn = C.copy()
        ok = den > 0
        Cn[ok] = num[ok] / den[ok, None]
        drift += np.sqrt(((Cn - C) ** 2).sum(axis=1)).max()
        C = Cn
    # nearest first, as documented
    for s in range(0, n, _BLOCK):
        e = min(n, s + _BLOCK)
        o = np.argsort(_dist_to(Xs[s:e], C, idx[s:e]), axis=1, kind="stable")
        idx[s:e] = np.take_along_axis(idx[s:e], o, 1)
        U[s:e] = np.take_along_axis(U[s:e], o, 1)
    return idx, U, C, it, conv


def _memberships_any(d: np.ndarray, m: float) -> np.ndarray:
    """u over the columns of d in any order (the nearest need not come first)."""
    e = 2.0 / (m - 1.0)
    dmin = d.min(axis=1, keepdims=True)
    zero = dmin[:, 0] == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (dmin / d) ** e
    U = r / r.sum(axis=1, keepdims=True)
    if zero.any():
        z = d[zero] == 0
        U[zero] = z / z.sum(axis=1, keepdims=True)
    return U
