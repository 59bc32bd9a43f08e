"""K-means into many small clusters: Lloyd's iterations with grid assignment and Hamerly's bounds.

See :mod:`.cluster` for the conventions shared with fuzzy C-means (seeding,
canonical order, the convergence warning); :func:`lloyd` is also FCM's warm
start.
"""

from __future__ import annotations

import numpy as np

from .centres import cell_size, centre_tree, nearest_centres
from .kernels.threads import Chunks
from .cluster import CentroidClustering
from .kernels import kmeans as kk
from ..errors import InvalidParameterError

__all__ = ["KMeans", "lloyd"]


class KMeans(CentroidClustering):
    """Lloyd's K-means with grid assignment and Hamerly's bounds.

    Stops when no point changes cluster (the paper) or after ``max_iter``
    iterations (then a :class:`~cloudsieve.errors.ConvergenceWarning`). An
    empty cluster keeps its previous centre.

    Parameters
    ----------
    n_clusters : int
    init : {"k-means++", "random", "kd-split"} or ndarray of shape (n_clusters, p)
        "kd-split": means of a balanced k-d split of a subsample (see
        :mod:`.cluster`); fewer iterations than k-means++ on surfaces.
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
        super().__init__(n_clusters, init=init, max_iter=max_iter, seed=seed, tol=tol)

    def _check_own_params(self) -> None:
        if not (0.0 <= self.tol < 1.0):
            raise InvalidParameterError(f"tol must be in [0, 1), got {self.tol!r}")

    def _random_start(self, Xs, c, rng):
        return Xs[np.sort(rng.choice(len(Xs), c, replace=False))].copy()

    def _iterate(self, Xs, C, threads):
        labels, C, n_iter, conv = lloyd(Xs, C, self.max_iter, threads, float(self.tol))
        return labels, C, n_iter, conv, {}

    def _unconverged(self, n: int, c: int) -> str:
        return (f"KMeans stopped at max_iter={self.max_iter} with points still changing cluster "
                f"(n={n}, n_clusters={c})")


_NEIGH = 8  # other centres each centre keeps as neighbours (bounds and cheap reassignment)


def _neighbour_lists(C, K):
    """The K nearest other centres of each centre ((c, K) indices, self
    excluded) and the distance T (c,) such that every other centre is at
    distance >= T (the farthest of the K + 1 returned by the tree)."""
    cd, ci = centre_tree(C).query(C, k=K + 1)
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


def lloyd(Xs, C, max_iter, threads, tol=0.0):
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
    than T_a - u) or, failing that, by a query over all centres
    (:func:`.centres.nearest_centres`).

    The passes over the points are compiled (:mod:`.kernels.kmeans`) and run
    in chunks of points on ``threads`` threads; every floating-point operation
    is the one of the numpy code they replaced, in the same order, so labels,
    centres and iteration counts do not depend on the thread count.

    Stops when at most tol * n points changed cluster (tol = 0: none, the
    paper's test) or at max_iter.

    Parameters
    ----------
    Xs : ndarray of shape (n, p), float64
        Valid points (canonically ordered by the estimators).
    C : ndarray of shape (c, p), float64
        Initial centres.
    max_iter : int
    threads : int
        Threads of the passes over the points.
    tol : float

    Returns
    -------
    labels : ndarray of shape (n,), int64
    centres : ndarray of shape (c, p), float64
        The means of the final clusters (an empty cluster keeps its centre).
    n_iter : int
    converged : bool
    """
    n, p = Xs.shape
    c = len(C)
    if c == 1:
        return np.zeros(n, dtype=np.int64), Xs.mean(axis=0, keepdims=True), 1, True
    with Chunks(threads) as chunks:
        return _lloyd(Xs, C, max_iter, tol, chunks)


def _lloyd(Xs, C, max_iter, tol, chunks):
    """:func:`lloyd` with c >= 2, its passes over the points run on ``chunks``."""
    n, p = Xs.shape
    c = len(C)
    neigh = _Neighbours(C, min(_NEIGH, c - 1))
    h = cell_size(C, 2)
    d, i = nearest_centres(Xs, C, 2, chunks, h)
    a = i[:, 0].copy()
    del i
    cumD = np.zeros(c)  # own moves since the lists were made
    cumM = np.zeros(c)  # largest moves over the lists since then
    L = d[:, 1].copy()  # l + cumM[a]
    R = d[:, 1] - d[:, 0]  # L - U with U = u - cumD[a]
    Umax = np.zeros(c)  # an upper bound on U over each cluster
    kk.cluster_max(a, np.ascontiguousarray(d[:, 0]), Umax)
    del d
    S, cnt = kk.cluster_sums(Xs, a, c)
    na = np.empty(n, dtype=np.int64)  # per iteration: the new label of a listed point (-1: query it)
    listed = np.empty(n, dtype=np.int64)  # each chunk [s, e) lists its points at listed[s:]
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
            def bring(s, e, T=T, near=near):
                um = np.zeros(c)
                kk.stale_bounds(a, L, R, cumD, cumM, T, near, s, e, um)
                return um
            Umax = np.maximum.reduce(chunks.map(bring, n))
            neigh.refresh(C)
            T, near, _ = neigh.at(C)
            cumD[:] = 0.0
            cumM[:] = 0.0
        Q = cumD + cumM
        Q[2.0 * (Umax + cumD) >= T] = np.inf  # far centres might come close: check every point
        def assign(s, e, T=T, near=near, Q=Q, C=C):
            um = np.zeros(c)
            cnt, _ = kk.assign_pass(Xs, a, L, R, Q, C, cumD, cumM, T, near, neigh.nb, s, e, na, um, listed)
            return s, cnt, um
        parts = chunks.map(assign, n)
        for _, _, um in parts:
            np.maximum(Umax, um, out=Umax)
        rows = np.concatenate([listed[s : s + cnt] for s, cnt, _ in parts])
        n_changed = 0
        if len(rows):
            q = np.flatnonzero(na[rows] < 0)
            d1 = np.full(len(rows), -1.0)
            low = np.empty(len(rows))
            if len(q):  # the nearest may be outside the neighbour list: all centres
                db, ib = nearest_centres(Xs, C, 2, chunks, h, rows[q])
                na[rows[q]] = ib[:, 0]
                d1[q] = db[:, 0]
                low[q] = db[:, 1]
            out, inn = np.zeros((c, p)), np.zeros((c, p))
            cnt_out, cnt_in = np.zeros(c), np.zeros(c)
            n_changed = kk.apply_moves(Xs, rows, a, na, d1, low, L, R, cumD, cumM, Umax, out, inn, cnt_out, cnt_in)
            if n_changed:
                S -= out
                S += inn
                cnt -= cnt_out
                cnt += cnt_in
        if n_changed <= limit:
            conv = True
            break
        if it % 20 == 0:  # refresh the running sums (no drift from +/- updates)
            S, cnt = kk.cluster_sums(Xs, a, c)
    # centres are the means of the final clusters
    S, cnt = kk.cluster_sums(Xs, a, c)
    ne = cnt > 0
    C = C.copy()
    C[ne] = S[ne] / cnt[ne, None]
    return a, C, it, conv
