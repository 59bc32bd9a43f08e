"""K-means and fuzzy C-means into many small clusters (DESIGN.md stage 3).

Both estimators follow scikit-learn's conventions: parameters in ``__init__``,
work in ``fit``, fitted state with a trailing underscore, one ``seed``, and a
:class:`ConvergenceWarning` when ``max_iter`` runs out.

Cost per iteration is O(n log c), not O(n c): nearest centres come from a
k-d tree over the centres (scipy's ``cKDTree``, queried on all cores), and
K-means skips the points whose assignment provably cannot change (Hamerly's
bounds, with the lower bound decaying by the largest move among each centre's
K nearest centres rather than among all; see :func:`_lloyd`). Fuzzy C-means keeps each
point's memberships for its ``n_nearest`` nearest centres only (all others are
zero); with ``n_nearest >= n_clusters`` this is exactly the textbook (dense)
FCM.

Determinism: the points are put in a canonical order (lexicographic by
coordinates) before any seeded step, so results do not depend on the input
order; the only randomness is ``np.random.default_rng(seed)``.

``init="k-means++"`` (default) seeds with k-means++ (D^2 sampling) on a uniform
subsample of ``max(1000, 4 * n_clusters)`` points (all points when fewer),
which keeps the seeding O(c^2) instead of O(n c) (FCM then runs 5 Lloyd
iterations before its own); ``init="kd-split"`` takes the means of a balanced
k-d split of a subsample (near-equal compact parts); ``init="random"``
reproduces the paper: K-means starts from ``n_clusters`` distinct random
points of X, FCM from random memberships (dense, computed in blocks: O(n c)
once). An array of shape (n_clusters, p) gives the initial centres.

K-means takes ``tol`` (default 0, the paper's "no point changed cluster"):
stop when at most ``tol * n`` points changed cluster in an iteration.
"""

from __future__ import annotations

import logging
import os
import warnings

import numpy as np
from scipy.spatial import cKDTree

from .entropy import _check_points
from ..errors import ConvergenceWarning, InvalidParameterError

__all__ = ["KMeans", "FuzzyCMeans", "ConvergenceWarning"]

logger = logging.getLogger(__name__)


def _canonical_order(X: np.ndarray) -> np.ndarray:
    """Lexicographic order of the rows (first column first): input order never matters.

    Same result as ``np.lexsort(X.T[::-1])`` (ties kept in input order), but a
    stable sort on the first column and a lexsort of the rows tied there only
    (lexsort's three passes over every row cost ~5x more on 1 M points)."""
    X = np.asarray(X)
    if X.ndim != 2 or len(X) < 2 or X.shape[1] < 2:
        return np.lexsort(X.T[::-1]) if X.ndim == 2 and X.shape[1] else np.arange(len(X))
    o = np.argsort(X[:, 0], kind="stable")
    x = X[o, 0]
    tie = x[1:] == x[:-1]
    if tie.any():
        t = np.zeros(len(x), dtype=bool)
        t[1:] |= tie
        t[:-1] |= tie
        pos = np.flatnonzero(t)  # runs of equal x, each contiguous in o
        sub = o[pos]  # in input order within each run (stable sort)
        Y = X[sub]
        o[pos] = sub[np.lexsort(Y.T[::-1])]
    return o


def _tree(C: np.ndarray) -> cKDTree:
    return cKDTree(C, balanced_tree=False, compact_nodes=False)


def _sample(X: np.ndarray, s: int, rng: np.random.Generator) -> np.ndarray:
    """s rows of X uniformly without replacement, in X's order (all when s >= n)."""
    n = len(X)
    return X if s >= n else X[np.sort(rng.choice(n, s, replace=False))]


_PP_BLOCK = 64  # k-means++: points per block of the running D^2 sums


def _kmeanspp(X: np.ndarray, c: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding (one trial per centre) on a uniform subsample of X.

    Exact D^2 sampling, written by hand (scikit-learn's is O(s c) per run and
    would add a dependency): the sample is sorted on its first coordinate, so a
    new centre x0 can only lower D^2 of the points within sqrt(max D^2) of x0
    along that axis, a window found by binary search; sums and maxima of D^2
    are kept per block of _PP_BLOCK points, so a draw costs O(s / B + B) and an
    update O(window + s / B) instead of O(s)."""
    S = _sample(X, min(len(X), max(1000, 4 * c)), rng)
    S = S[np.argsort(S[:, 0], kind="stable")]
    s, p = S.shape
    B = _PP_BLOCK
    nb = -(-s // B)
    cols = [np.ascontiguousarray(S[:, j]) for j in range(p)]
    x = cols[0]
    d2 = np.full(nb * B, 0.0)  # padded with zeros (never drawn)
    chosen = np.empty(c, dtype=np.int64)
    chosen[0] = rng.integers(s)
    d2[:s] = sum((cols[j] - S[chosen[0], j]) ** 2 for j in range(p))
    bsum = d2.reshape(nb, B).sum(axis=1)
    bmax = d2.reshape(nb, B).max(axis=1)
    for k in range(1, c):
        total = bsum.sum()
        if total > 0:
            cum = np.cumsum(bsum)
            r = rng.random() * cum[-1]
            b = min(int(np.searchsorted(cum, r, side="right")), nb - 1)
            r -= cum[b - 1] if b else 0.0
            within = np.cumsum(d2[b * B : (b + 1) * B])
            nxt = b * B + min(int(np.searchsorted(within, r, side="right")), B - 1)
            while nxt >= s or d2[nxt] == 0:  # rounding landed on a zero or padding: step back
                nxt -= 1
        else:  # every remaining point coincides with a centre
            nxt = int(rng.integers(s))
        chosen[k] = nxt
        reach = np.sqrt(bmax.max())
        lo = int(np.searchsorted(x, x[nxt] - reach, side="left"))
        hi = int(np.searchsorted(x, x[nxt] + reach, side="right"))
        lo, hi = (lo // B) * B, min(-(-hi // B) * B, s)
        dn = sum((cols[j][lo:hi] - S[nxt, j]) ** 2 for j in range(p))
        np.minimum(d2[lo:hi], dn, out=d2[lo:hi])
        blo, bhi = lo // B, -(-hi // B)
        part = d2[blo * B : bhi * B].reshape(-1, B)
        bsum[blo:bhi] = part.sum(axis=1)
        bmax[blo:bhi] = part.max(axis=1)
    return S[chosen].copy()


def _kd_split(X: np.ndarray, c: int, rng: np.random.Generator) -> np.ndarray:
    """Centres of a balanced k-d split of a uniform subsample of X.

    The sample (32 points per cluster, at least 10,000) is cut recursively
    across its widest coordinate into two parts holding k1 = k // 2 and
    k - k1 clusters' shares of the points, until each part holds one
    cluster's; the centres are the parts' means. Near-equal, compact parts:
    Lloyd's iterations start close to a balanced partition. All parts of a
    level are cut at once: one stable sort of the sample by (part, coordinate)."""
    S = _sample(X, max(10_000, 32 * c), rng)
    s, p = S.shape
    perm = np.arange(s)
    start = np.zeros(1, dtype=np.int64)
    size = np.array([s], dtype=np.int64)
    k = np.array([c], dtype=np.int64)
    while (k > 1).any():
        P = np.take(S, perm, axis=0)
        ext = np.maximum.reduceat(P, start, axis=0) - np.minimum.reduceat(P, start, axis=0)
        axis = np.argmax(ext, axis=1)
        part = np.repeat(np.arange(len(start)), size)
        key = P[np.arange(s), axis[part]]
        o = np.argsort(key)  # deterministic; ties in any fixed order
        perm = perm[o[np.argsort(part[o], kind="stable")]]  # by part, then key
        split = k > 1
        k1 = k // 2
        cut = np.clip(np.round(size * k1 / np.maximum(k, 1)).astype(np.int64), 1, np.maximum(size - 1, 1))
        # children in order: (start, cut, k1), (start + cut, size - cut, k - k1); unsplit parts kept
        n_new = len(k) + int(split.sum())
        ns, nz, nk = np.empty(n_new, np.int64), np.empty(n_new, np.int64), np.empty(n_new, np.int64)
        pos = np.arange(len(k)) + np.cumsum(split) - split
        ns[pos], nz[pos], nk[pos] = start, np.where(split, cut, size), np.where(split, k1, k)
        q = pos[split] + 1
        ns[q], nz[q], nk[q] = start[split] + cut[split], size[split] - cut[split], (k - k1)[split]
        start, size, k = ns, nz, nk
    P = np.take(S, perm, axis=0)
    means = np.add.reduceat(P, start, axis=0) / size[:, None]
    return np.repeat(means, k, axis=0)[:c]


INITS = ("k-means++", "random", "kd-split")


def _initial_centres(Xs, c, init, rng):
    """Centres to start from (init "random" is handled by each estimator)."""
    if isinstance(init, str) and init == "k-means++":
        return _kmeanspp(Xs, c, rng)
    if isinstance(init, str):
        return _kd_split(Xs, c, rng)
    return np.array(init, dtype=np.float64)


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
        if init not in INITS:
            raise InvalidParameterError(
                f"init must be 'k-means++', 'random', 'kd-split' or an array of centres, got {init!r}")
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
    init : {"k-means++", "random", "kd-split"} or ndarray of shape (n_clusters, p)
        "kd-split": means of a balanced k-d split of a subsample (see
        :func:`_kd_split`); fewer iterations than k-means++ on surfaces.
    max_iter : int
    seed : int
    tol : float, default 0.0
        Stop when at most ``tol * n`` points changed cluster in the last
        iteration; 0 is the paper's test (no point changed). With tol > 0 the
        labels are the last assignment and the centres their means.

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

    def __init__(self, n_clusters: int, *, init="k-means++", max_iter: int = 300, seed: int = 0,
                 tol: float = 0.0):
        self.n_clusters = n_clusters
        self.init = init
        self.max_iter = max_iter
        self.seed = seed
        self.tol = tol

    def fit(self, points, workers: int | None = None) -> KMeans:
        """Cluster ``points`` (array of shape (n, p)); returns self."""
        X = _check_fit_args(points, self.n_clusters, self.max_iter, self.init)
        if not (0.0 <= self.tol < 1.0):
            raise InvalidParameterError(f"tol must be in [0, 1), got {self.tol!r}")
        c = int(self.n_clusters)
        workers = int(workers or os.cpu_count() or 1)
        order = _canonical_order(X)
        Xs = X[order]
        rng = np.random.default_rng(self.seed)
        if isinstance(self.init, str) and self.init == "random":
            C = Xs[np.sort(rng.choice(len(Xs), c, replace=False))].copy()
        else:
            C = _initial_centres(Xs, c, self.init, rng)
        labels, C, n_iter, conv = _lloyd(Xs, C, self.max_iter, workers, float(self.tol))
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


_NEIGH = 8  # other centres each centre keeps as neighbours (bounds and cheap reassignment)


def _neighbour_lists(C, K):
    """The K nearest other centres of each centre ((c, K) indices, self
    excluded) and the distance T (c,) such that every other centre is at
    distance >= T (the farthest of the K + 1 returned by the tree)."""
    cd, ci = _tree(C).query(C, k=K + 1)
    own = np.arange(len(C))[:, None]
    self_at = ci == own
    # self is usually in column 0; with duplicate centres it may be elsewhere (or absent)
    nb = np.where(self_at[:, :1], ci[:, 1:], ci[:, :K])
    fix = ~self_at[:, 0] & self_at[:, 1:].any(axis=1)
    if fix.any():  # drop self from the list, keep K others
        rows = np.flatnonzero(fix)
        nb[rows] = np.array([r[r != j][:K] for j, r in zip(rows, ci[rows])])
    return nb, cd[:, K].copy()


class _Neighbours:
    """Neighbour lists of the centres, re-queried only when the centres moved
    enough since the last query to weaken T much.

    Between queries a list stays valid with T_a lowered by the move of a plus
    the largest move of any centre since the query (every non-listed centre j
    had |c_a - c_j| >= T_a then). Distances to the listed neighbours are
    computed exactly every iteration (c K of them)."""

    def __init__(self, C, K):
        self.K = K
        self.refresh(C)

    def refresh(self, C):
        self.nb, self.T0 = _neighbour_lists(C, self.K)
        self.Tmean = float(self.T0.mean())
        self.C0 = C.copy()

    def at(self, C):
        """(T, nearest other centre distance, stale) for centres C."""
        mv = np.sqrt(((C - self.C0) ** 2).sum(axis=1))
        slack = mv.max()
        T = self.T0 - mv - slack
        dn = np.zeros(self.nb.shape)
        for j in range(C.shape[1]):
            dn += (np.take(C[:, j], self.nb) - C[:, j : j + 1]) ** 2
        near = np.minimum(np.sqrt(dn.min(axis=1)), T)
        return T, near, slack > 0.05 * self.Tmean


def _lloyd(Xs, C, max_iter, workers, tol=0.0):
    """Lloyd's iterations from centres C; exactly the plain algorithm's labels.

    Work per iteration is O(c K) for the centres, O(n) for one gather and
    compare, and O(active) for the points whose nearest centre may have
    changed. Per point x (label a) we keep an upper bound u(x) on the distance
    to its centre and a lower bound l(x) on the distance to every other
    centre (Hamerly); x keeps its label while u < l. Each centre keeps a list
    of its K nearest other centres; every centre j outside the list is at
    distance >= T_a from centre a, so >= T_a - u(x) from x. Hence, as long
    as 2 u(x) <= T_a, only listed centres can come closer than u(x), and l may
    decay by the largest move M_a over the list instead of over all centres
    (Hamerly's choice, far looser for many small clusters). Bounds are kept
    lazily: with D_a, M_a cumulated since the list was made,
    u(x) = U(x) + D_a and l(x) = L(x) - M_a, so the test is
    R(x) = L(x) - U(x) > D_a + M_a: one gather of a per-centre array, which
    is made +inf for the centres where 2 (max U + D_a) > T_a (then all their
    points are checked). When the lists are re-made, l is first brought to a
    bound over all centres: min(l - M_a, T_a - u). Points failing the test
    get their exact u and l = max(min(L - M_a, T_a - u), h_a - u) (h_a the
    distance from a to its nearest other centre); those still failing are
    reassigned among their centre's list (exact when the best found is closer
    than T_a - u) or, failing that, by a k-d tree query over all centres.

    Stops when at most tol * n points changed cluster (tol = 0: none, the
    paper's test) or at max_iter.
    """
    n, p = Xs.shape
    c = len(C)
    if c == 1:
        return np.zeros(n, dtype=np.int64), Xs.mean(axis=0, keepdims=True), 1, True
    neigh = _Neighbours(C, min(_NEIGH, c - 1))
    d, i = _tree(C).query(Xs, k=2, workers=workers)
    a = i[:, 0].astype(np.int64)
    del i
    cumD = np.zeros(c)  # own moves since the lists were made
    cumM = np.zeros(c)  # largest moves over the lists since then
    L = d[:, 1].copy()  # l + cumM[a]
    R = d[:, 1] - d[:, 0]  # L - U with U = u - cumD[a]
    Umax = np.zeros(c)  # an upper bound on U over each cluster
    np.maximum.at(Umax, a, d[:, 0])
    del d
    S, cnt = _sums(Xs, a, c)
    limit = tol * n
    conv = False
    it = 0
    for it in range(1, max_iter + 1):
        nonempty = cnt > 0
        Cn = C.copy()
        Cn[nonempty] = S[nonempty] / cnt[nonempty, None]
        delta = np.sqrt(((Cn - C) ** 2).sum(axis=1))
        C = Cn
        T, near, stale = neigh.at(C)
        cumD += delta
        cumM += np.take(delta, neigh.nb).max(axis=1)
        if stale:  # bounds over all centres now, then new lists (cumulated moves from 0)
            U = L - R
            ub = U + np.take(cumD, a)
            lb = np.maximum(np.minimum(L - np.take(cumM, a), np.take(T, a) - ub), np.take(near, a) - ub)
            neigh.refresh(C)
            T, near, _ = neigh.at(C)
            cumD[:] = 0.0
            cumM[:] = 0.0
            L = lb
            R = lb - ub
            Umax[:] = 0.0
            np.maximum.at(Umax, a, ub)
        Q = cumD + cumM
        Q[2.0 * (Umax + cumD) >= T] = np.inf  # far centres might come close: check every point
        act = np.flatnonzero(~(R > np.take(Q, a)))
        n_changed = 0
        if len(act):
            aa = np.take(a, act)
            Xa = np.take(Xs, act, axis=0)
            u = np.sqrt(((Xa - np.take(C, aa, axis=0)) ** 2).sum(axis=1))
            low = np.maximum(np.minimum(np.take(L, act) - np.take(cumM, aa), np.take(T, aa) - u),
                             np.take(near, aa) - u)
            ok = u < low
            done = act[ok]
            aok = aa[ok]
            L[done] = low[ok] + np.take(cumM, aok)
            R[done] = low[ok] - u[ok] + np.take(cumD, aok) + np.take(cumM, aok)
            todo = np.flatnonzero(~ok)
            act, aa, Xa, u = act[todo], aa[todo], np.take(Xa, todo, axis=0), u[todo]
        if len(act):
            na, d1, d2 = _reassign(Xa, aa, u, C, neigh.nb, T, workers)
            moved = np.flatnonzero(na != aa)
            n_changed = len(moved)
            if n_changed:
                old = aa[moved]
                new = na[moved]
                Xc = np.take(Xa, moved, axis=0)
                for j in range(p):
                    S[:, j] -= np.bincount(old, weights=Xc[:, j], minlength=c)
                    S[:, j] += np.bincount(new, weights=Xc[:, j], minlength=c)
                cnt -= np.bincount(old, minlength=c)
                cnt += np.bincount(new, minlength=c)
            a[act] = na
            cD = np.take(cumD, na)
            L[act] = d2 + np.take(cumM, na)
            R[act] = d2 - d1 + cD + np.take(cumM, na)
            np.maximum.at(Umax, na, d1 - cD)
        if n_changed <= limit:
            conv = True
            break
        if it % 20 == 0:  # refresh the running sums (no drift from +/- updates)
            S, cnt = _sums(Xs, a, c)
    # centres are the means of the final clusters
    S, cnt = _sums(Xs, a, c)
    ne = cnt > 0
    C = C.copy()
    C[ne] = S[ne] / cnt[ne, None]
    return a, C, it, conv


def _reassign(Xa, aa, u, C, nb, T, workers):
    """Nearest centre of each row of Xa (own centre aa at distance u) and a
    lower bound on the distance to every other centre: (labels, d1, l).

    First among the own centre and its K neighbours (a gather, cheaper than a
    tree query); that answer is exact when the best distance found is below
    T_a - u, the distance below which no non-neighbour centre can be. The
    rest go to a k-d tree over all centres."""
    cand = np.concatenate([aa[:, None], np.take(nb, aa, axis=0)], axis=1)  # (m, K + 1)
    D = np.zeros(cand.shape)  # squared distances
    for j in range(Xa.shape[1]):
        diff = np.take(np.ascontiguousarray(C[:, j]), cand)
        np.subtract(Xa[:, j : j + 1], diff, out=diff)
        np.multiply(diff, diff, out=diff)
        D += diff
    rows = np.arange(len(D))
    k1 = np.argmin(D, axis=1)
    d1 = np.sqrt(D[rows, k1])
    D[rows, k1] = np.inf
    d2 = np.sqrt(_rows(np.minimum, D))
    far = np.take(T, aa) - u
    na = cand[rows, k1]
    low = np.minimum(d2, far)
    bad = np.flatnonzero(~(d1 < far))
    if len(bad):
        w = workers if len(bad) >= 20_000 else 1  # threads cost more than they save on small queries
        d, i = _tree(C).query(np.take(Xa, bad, axis=0), k=2, workers=w)
        na[bad] = i[:, 0]
        d1[bad] = d[:, 0]
        low[bad] = d[:, 1]
    return na, d1, low


class FuzzyCMeans:
    """Fuzzy C-means with memberships over the ``n_nearest`` nearest centres.

    u_ij = 1 / sum_l (d_ij / d_il)^(2/(m-1)) over the point's L = min(n_nearest,
    n_clusters) nearest centres (0 for the others), centres the u^m-weighted
    means; stops when the largest change of a membership between two
    iterations is below ``tol`` (compared as full n x c matrices), when
    ``label_tol`` is given and at most ``label_tol * n`` hard labels changed
    since the previous update, or after ``max_iter`` membership updates (then
    a :class:`ConvergenceWarning`).
    Hard label: the centre of largest membership (the nearest for a tie).

    Parameters
    ----------
    n_clusters : int
    m : float
        Fuzzifier, > 1 (2 in the paper).
    tol : float
    n_nearest : int
    init : {"k-means++", "random", "kd-split"} or ndarray of shape (n_clusters, p)
        "k-means++": k-means++ seeding then 5 Lloyd iterations (fewer FCM
        iterations to ``tol``); "random": the paper's random memberships.
    max_iter : int
    seed : int
    label_tol : float, optional
        Also stop when at most ``label_tol * n`` points changed hard label in
        the last update (the test :class:`KMeans` applies with its ``tol``).
        None (the default) keeps the paper's membership test alone.

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
        True when ``tol`` or ``label_tol`` stopped it (not ``max_iter``).
    """

    def __init__(self, n_clusters: int, *, m: float = 2.0, tol: float = 1e-5, n_nearest: int = 8,
                 init="k-means++", max_iter: int = 300, seed: int = 0, label_tol: float | None = None):
        self.n_clusters = n_clusters
        self.label_tol = label_tol
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
        if self.label_tol is not None and not (0.0 <= self.label_tol < 1.0):
            raise InvalidParameterError(f"label_tol must be None or in [0, 1), got {self.label_tol!r}")
        c = int(self.n_clusters)
        L = min(int(self.n_nearest), c)
        workers = int(workers or os.cpu_count() or 1)
        order = _canonical_order(X)
        Xs = X[order]
        rng = np.random.default_rng(self.seed)
        if isinstance(self.init, str) and self.init == "random":
            C = _random_membership_centres(Xs, c, self.m, rng)
        else:
            C = _initial_centres(Xs, c, self.init, rng)
            if isinstance(self.init, str) and self.init == "k-means++" and c > 1:
                # a few Lloyd iterations first: FCM's slow start (centres far from
                # a balanced partition) is cheaper to cover with K-means
                C = _lloyd(Xs, C, _FCM_KM_ITERS, workers)[1]
        label_tol = None if self.label_tol is None else float(self.label_tol)
        idx, U, C, n_iter, conv = _fcm(Xs, C, L, float(self.m), float(self.tol), int(self.max_iter), workers, label_tol)
        if not conv:
            also = "" if label_tol is None else f" and more than label_tol={self.label_tol} of the hard labels changing"
            warnings.warn(
                f"FuzzyCMeans stopped at max_iter={self.max_iter} with membership change >= tol={self.tol}{also} "
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


_FCM_KM_ITERS = 5  # Lloyd iterations before FCM when init="k-means++"
_BLOCK = 1 << 17  # rows per block in FCM: bounds the temporaries to O(block * L)
_FCM_RING = 8  # centres beyond the L nearest whose distances FCM keeps exact (see _fcm)


def _rows(op, a):
    """op (np.minimum / np.maximum) over each row of a 2-D array with few columns:
    one vectorised pass per column, ~7x faster than ``a.min(axis=1)`` on
    (131072, 8) (measured), same values (min and max are exact)."""
    out = a[:, 0].copy()
    for j in range(1, a.shape[1]):
        op(out, a[:, j], out=out)
    return out


def _dist_to(Xs, C, idx):
    """Distances from each row of Xs to the centres idx of that row (n, L)."""
    return np.sqrt(_sqdist_to(Xs, C, idx))


def _sqdist_to(Xs, C, idx):
    """Squared distances, one coordinate at a time (no (n, L, p) temporary)."""
    D2 = np.zeros(idx.shape)
    for j in range(Xs.shape[1]):
        diff = Xs[:, j : j + 1] - np.take(C[:, j], idx)
        D2 += diff * diff
    return D2


def _fcm(Xs, C, L, m, tol, max_iter, workers, label_tol=None):
    """FCM iterations, in blocks of points (memory O(n L) for the memberships
    plus O(block L) temporaries). Stops when the membership change is below
    ``tol`` or, with ``label_tol``, when at most ``label_tol * n`` hard labels
    changed (the hard label in a row sorted by index: the first largest
    membership, which is the nearest centre, lowest index on a tie, as in
    :meth:`FuzzyCMeans.fit`).

    The k-d tree query of a point returns its L nearest centres (the set S)
    and the E = min(_FCM_RING, c - L) next ones (the ring Q), whose exact
    distances are computed again at every update (cheaper than a query): a
    ring centre that came closer than a member of S swaps in, so S stays the
    L nearest of S and Q. With R the (L+E+1)-th nearest distance at the last
    query and D the sum, over the updates since, of the largest move of any
    centre, every centre outside S and Q is still >= R - D away; the point is
    queried again only when its L-th nearest distance reaches R - D (with
    the ring, R is far beyond the L-th nearest, so this is rare; without it,
    R was the (L+1)-th and 43% of the points were queried again at every
    update, measured at 1 M points into 2,500 clusters). Each row of S is
    kept sorted by index, so an unchanged set is an equal row and the
    membership change is a plain difference."""
    n, p = Xs.shape
    c = len(C)
    extra = L < c
    E = min(_FCM_RING, c - L)
    K = L + E + (1 if L + E < c else 0)  # neighbours per query
    idx = np.zeros((n, L), dtype=np.int64)
    ring = np.zeros((n, E), dtype=np.int64)
    U = np.zeros((n, L))
    reach = np.full(n, np.inf)  # R - D (inf: the ring holds every other centre)
    hard = np.full(n, -1, dtype=np.int64) if label_tol is not None else None
    have = False
    conv = False
    it = 0
    for it in range(1, max_iter + 1):
        tree = None
        ch = 0.0
        relabelled = 0
        num = np.zeros((c, p))
        den = np.zeros(c)
        for s in range(0, n, _BLOCK):
            e = min(n, s + _BLOCK)
            Xb = Xs[s:e]
            Qb = ring[s:e]
            if not have:
                Ib = np.empty((e - s, L), dtype=np.int64)
                D2 = None
                redo = np.arange(e - s)
                swap = redo[:0]
            else:
                Ib = idx[s:e].copy()
                D2 = _sqdist_to(Xb, C, Ib)
                redo = swap = np.zeros(0, dtype=np.int64)
                if extra:
                    D2q = _sqdist_to(Xb, C, Qb)
                    top = _rows(np.maximum, D2)
                    swap = np.flatnonzero(_rows(np.minimum, D2q) < top)
                    if len(swap):  # a ring centre came closer than a member: the L nearest of S and Q
                        cand = np.concatenate([Ib[swap], Qb[swap]], axis=1)
                        dc = np.concatenate([D2[swap], D2q[swap]], axis=1)
                        o = np.argsort(dc, axis=1, kind="stable")
                        cand = np.take_along_axis(cand, o, 1)
                        dc = np.take_along_axis(dc, o, 1)
                        so = np.argsort(cand[:, :L], axis=1)
                        Ib[swap] = np.take_along_axis(cand[:, :L], so, 1)
                        D2[swap] = np.take_along_axis(dc[:, :L], so, 1)
                        Qb[swap] = cand[:, L:]
                        top[swap] = dc[:, L - 1]
                    rb = reach[s:e]
                    redo = np.flatnonzero(~(top < np.where(rb > 0, rb * rb, -1.0)))
            if len(redo):
                if tree is None:
                    tree = _tree(C)
                w = workers if len(redo) >= 20_000 else 1
                Xr = np.take(Xb, redo, axis=0)
                d, i = tree.query(Xr, k=K, workers=w)
                if d.ndim == 1:
                    d, i = d[:, None], i[:, None]
                if K > L + E:
                    reach[s + redo] = d[:, L + E]
                Ib[redo] = np.sort(i[:, :L], axis=1)
                Qb[redo] = i[:, L : L + E]
                if D2 is None:
                    D2 = _sqdist_to(Xb, C, Ib)
                else:
                    D2[redo] = _sqdist_to(Xr, C, Ib[redo])
            Ub = _memberships_sq(D2, m)
            if have:
                rows = np.union1d(redo, swap)
                moved = rows[~(np.take(Ib, rows, axis=0) == np.take(idx[s:e], rows, axis=0)).all(axis=1)]
                if len(moved):
                    ch = max(ch, _max_change(idx[s + moved], U[s + moved], Ib[moved], Ub[moved]))
                    Ub_same = Ub.copy()
                    Ub_same[moved] = U[s + moved]  # their change is counted above
                    ch = max(ch, float(np.abs(Ub_same - U[s:e]).max()))
                else:
                    ch = max(ch, float(np.abs(Ub - U[s:e]).max()))
            if hard is not None:
                hb = np.take_along_axis(Ib, np.argmax(Ub, axis=1)[:, None], 1)[:, 0]
                relabelled += int(np.count_nonzero(hb != hard[s:e]))
                hard[s:e] = hb
            idx[s:e] = Ib
            U[s:e] = Ub
            W = Ub * Ub if m == 2.0 else Ub**m
            flat = Ib.ravel()
            den += np.bincount(flat, weights=W.ravel(), minlength=c)
            for j in range(p):
                num[:, j] += np.bincount(flat, weights=(W * Xb[:, j : j + 1]).ravel(), minlength=c)
        if have and (ch < tol or (label_tol is not None and relabelled <= label_tol * n)):
            conv = True
            break
        have = True
        if it == max_iter:
            break
        Cn = C.copy()
        ok = den > 0
        Cn[ok] = num[ok] / den[ok, None]
        reach -= np.sqrt(((Cn - C) ** 2).sum(axis=1)).max()
        C = Cn
    # nearest first, as documented
    for s in range(0, n, _BLOCK):
        e = min(n, s + _BLOCK)
        o = np.argsort(_dist_to(Xs[s:e], C, idx[s:e]), axis=1, kind="stable")
        idx[s:e] = np.take_along_axis(idx[s:e], o, 1)
        U[s:e] = np.take_along_axis(U[s:e], o, 1)
    return idx, U, C, it, conv


def _memberships_sq(d2: np.ndarray, m: float) -> np.ndarray:
    """u over the columns of the squared distances d2 (any order):
    u_ij = 1 / sum_l (d_ij / d_il)^(2/(m-1)) = 1 / sum_l (d2_ij / d2_il)^(1/(m-1))."""
    e = 1.0 / (m - 1.0)
    dmin = _rows(np.minimum, d2)[:, None]
    zero = dmin[:, 0] == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        r = dmin / d2
        if e != 1.0:
            r **= e
    U = r / r.sum(axis=1, keepdims=True)
    if zero.any():
        z = d2[zero] == 0
        U[zero] = z / z.sum(axis=1, keepdims=True)
    return U
