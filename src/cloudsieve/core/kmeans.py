"""K-means into many small clusters: Lloyd's iterations with grid assignment and Hamerly's bounds (conventions: :mod:`.cluster`)."""

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

    Stops when no point changes cluster (the paper) or after ``max_iter`` iterations
    (then a :class:`~cloudsieve.errors.ConvergenceWarning`). An empty cluster keeps its centre.

    Parameters
    ----------
    n_clusters : int
    init : {"k-means++", "random", "kd-split"} or ndarray of shape (n_clusters, p)
        See :mod:`.cluster`; "kd-split" needs fewer iterations on surfaces.
    max_iter : int
    seed : int
    tol : float, default 0.0
        Stop when at most ``tol * n`` points changed cluster; 0 is the paper's test.

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
    """The K nearest other centres of each centre ((c, K), self excluded) and T (c,): every other centre is >= T away."""
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
    """Neighbour lists of the centres, re-queried only when the centres moved enough to weaken T much.

    Between queries T_a is lowered by a's move plus the largest move of any centre.
    """

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
    """Lloyd's iterations from centres C (c, p) on valid, canonically ordered Xs (n, p); exactly the plain algorithm's labels.

    Hamerly's bounds per point x of label a: upper u(x) to its centre, lower l(x) to
    every other; x keeps its label while u < l. Each centre lists its K nearest
    other centres, all others at >= T_a; while 2 u(x) <= T_a only listed centres can
    come closer, so l decays by the largest move over the list, not over all
    centres. Bounds are kept lazily (u = U + D_a, l = L - M_a, test
    L - U > D_a + M_a). Failing points are reassigned among the list, else by
    :func:`.centres.nearest_centres`. Passes are compiled (:mod:`.kernels.kmeans`),
    in a fixed floating-point order: results do not depend on ``threads``.
    Stops when at most tol * n points changed cluster, or at max_iter.

    Returns labels (n,) int64, centres (c, p) (means of the final clusters; an empty
    cluster keeps its centre), n_iter, converged.
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
