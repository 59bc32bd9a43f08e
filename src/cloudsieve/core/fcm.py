"""Fuzzy C-means into many small clusters, with memberships over the nearest centres only.

See :mod:`.cluster` for the conventions shared with K-means (seeding,
canonical order, the convergence warning).
"""

from __future__ import annotations

import numpy as np

from .cluster import CentroidClustering, centre_tree, rowwise
from .kmeans import lloyd
from ..errors import InvalidParameterError

__all__ = ["FuzzyCMeans"]


class FuzzyCMeans(CentroidClustering):
    """Fuzzy C-means with memberships over the ``n_nearest`` nearest centres.

    u_ij = 1 / sum_l (d_ij / d_il)^(2/(m-1)) over the point's L = min(n_nearest,
    n_clusters) nearest centres (0 for the others), centres the u^m-weighted
    means; stops when the largest change of a membership between two
    iterations is below ``tol`` (compared as full n x c matrices), when
    ``label_tol`` is given and at most ``label_tol * n`` hard labels changed
    since the previous update, or after ``max_iter`` membership updates (then
    a :class:`~cloudsieve.errors.ConvergenceWarning`).
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
        the last update (the test :class:`~.kmeans.KMeans` applies with its ``tol``).
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
        super().__init__(n_clusters, init=init, max_iter=max_iter, seed=seed, tol=tol)
        self.label_tol = label_tol
        self.m = m
        self.n_nearest = n_nearest

    def _check_own_params(self) -> None:
        if not (np.isfinite(self.m) and self.m > 1):
            raise InvalidParameterError(f"fuzzifier m must be > 1, got {self.m!r}")
        if not (self.tol > 0):
            raise InvalidParameterError(f"tol must be > 0, got {self.tol!r}")
        if int(self.n_nearest) != self.n_nearest or self.n_nearest < 1:
            raise InvalidParameterError(f"n_nearest must be an integer >= 1, got {self.n_nearest!r}")
        if self.label_tol is not None and not (0.0 <= self.label_tol < 1.0):
            raise InvalidParameterError(f"label_tol must be None or in [0, 1), got {self.label_tol!r}")

    def _random_start(self, Xs, c, rng):
        return _random_membership_centres(Xs, c, self.m, rng)

    def _start(self, Xs, c, rng, threads):
        C = super()._start(Xs, c, rng, threads)
        if isinstance(self.init, str) and self.init == "k-means++" and c > 1:
            # a few Lloyd iterations first: FCM's slow start (centres far from
            # a balanced partition) is cheaper to cover with K-means
            C = lloyd(Xs, C, _FCM_KM_ITERS, threads)[1]
        return C

    def _iterate(self, Xs, C, threads):
        L = min(int(self.n_nearest), len(C))
        label_tol = None if self.label_tol is None else float(self.label_tol)
        idx, U, C, n_iter, conv = _fcm(Xs, C, L, float(self.m), float(self.tol), int(self.max_iter), threads, label_tol)
        best = np.argmax(U, axis=1)
        lab = idx[np.arange(len(idx)), best]
        return lab, C, n_iter, conv, {"memberships_": U, "membership_indices_": idx}

    def _unconverged(self, n: int, c: int) -> str:
        also = "" if self.label_tol is None else f" and more than label_tol={self.label_tol} of the hard labels changing"
        return (f"FuzzyCMeans stopped at max_iter={self.max_iter} with membership change >= tol={self.tol}{also} "
                f"(n={n}, n_clusters={c})")


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


def _fcm(Xs, C, L, m, tol, max_iter, threads, label_tol=None):
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
                    top = rowwise(np.maximum, D2)
                    swap = np.flatnonzero(rowwise(np.minimum, D2q) < top)
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
                    tree = centre_tree(C)
                w = threads if len(redo) >= 20_000 else 1
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
    dmin = rowwise(np.minimum, d2)[:, None]
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
