"""Fuzzy C-means into many small clusters, memberships over the nearest centres only (conventions: :mod:`.cluster`)."""

from __future__ import annotations

import numpy as np

from .centres import cell_size, centre_tree, no_lists, candidate_lists, ring_grid
from .kernels.threads import Chunks
from .cluster import CentroidClustering
from .kernels import fcm as kf
from .kmeans import lloyd
from ..errors import InvalidParameterError

__all__ = ["FuzzyCMeans"]


class FuzzyCMeans(CentroidClustering):
    """Fuzzy C-means with memberships over the ``n_nearest`` nearest centres.

    u_ij = 1 / sum_l (d_ij / d_il)^(2/(m-1)) over the L = min(n_nearest, n_clusters)
    nearest centres (0 for the others); centres are the u^m-weighted means. Stops
    when the largest membership change is below ``tol``, when at most
    ``label_tol * n`` hard labels changed, or after ``max_iter`` updates (then a
    :class:`~cloudsieve.errors.ConvergenceWarning`). Hard label: largest membership
    (nearest on a tie).

    Parameters
    ----------
    n_clusters : int
    m : float
        Fuzzifier, > 1 (2 in the paper).
    tol : float
    n_nearest : int
    init : {"k-means++", "random", "kd-split"} or ndarray of shape (n_clusters, p)
        "k-means++" adds 5 Lloyd iterations; "random": the paper's random memberships.
    max_iter : int
    seed : int
    label_tol : float, optional
        None (default): the paper's membership test alone.

    Attributes
    ----------
    cluster_centers_ : ndarray of shape (n_clusters, p)
        The centres the final memberships were computed from.
    labels_ : ndarray of shape (n,), int64
    memberships_ : ndarray of shape (n, L), float64
        Memberships to the L nearest centres, nearest first.
    membership_indices_ : ndarray of shape (n, L), int64
    n_iter_ : int
        Membership updates done.
    converged_ : bool
        True when ``tol`` or ``label_tol`` stopped it.
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
            # a few Lloyd iterations first: cheaper than FCM's slow start
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
    """max |U1 - U0| over the full n x c matrices, from their kept entries (rows in any order, absent entries 0)."""
    if len(idx0) == 0:
        return 0.0
    return float(kf.max_change(np.ascontiguousarray(idx0, dtype=np.int64), np.ascontiguousarray(U0, dtype=np.float64),
                               np.ascontiguousarray(idx1, dtype=np.int64), np.ascontiguousarray(U1, dtype=np.float64)))


_FCM_KM_ITERS = 5  # Lloyd iterations before FCM when init="k-means++"
_BLOCK = 1 << 17  # rows per block of FCM's centre sums (the order of the additions)
_FCM_RING = 8  # centres beyond the L nearest whose distances FCM keeps exact (see _fcm)


def _fcm(Xs, C, L, m, tol, max_iter, threads, label_tol=None):
    """FCM iterations (memory O(n (L + E))); stops on ``tol`` or ``label_tol`` as :class:`FuzzyCMeans`.

    A query returns a point's L nearest centres S and the E = min(_FCM_RING, c - L)
    next (the ring Q), whose distances are recomputed every update so ring centres
    can swap in. With R the (L+E+1)-th distance at the last query and D the summed
    largest centre moves since, all other centres are >= R - D away; the point is
    queried again only when its L-th distance reaches R - D. Rows of S stay sorted by
    index. Compiled in :mod:`.kernels.fcm`; centre sums per block of ``_BLOCK``
    points in fixed order, so nothing depends on ``threads``.
    """
    with Chunks(threads) as chunks:
        return _fcm_run(Xs, C, L, m, tol, max_iter, chunks, label_tol)


def _fcm_run(Xs, C, L, m, tol, max_iter, chunks, label_tol):
    n, p = Xs.shape
    c = len(C)
    E = min(_FCM_RING, c - L)
    K = L + E + (1 if L + E < c else 0)  # neighbours per query
    ix = np.int32 if c < 2**31 else np.int64  # centre indices: int32 halves the memory traffic of the updates
    idx = np.zeros((n, L), dtype=ix)
    ring = np.zeros((n, E), dtype=ix)
    U = np.zeros((n, L))
    reach = np.full(n, np.inf)  # R - D (inf: the ring holds every other centre)
    hard = np.full(n if label_tol is not None else 0, -1, dtype=ix)
    flag = np.empty(n, dtype=np.uint8)  # a query with tied distances, left to the tree
    e = 1.0 / (m - 1.0)
    h = cell_size(C, K)
    block = int(_BLOCK)
    have = False
    conv = False
    it = 0
    for it in range(1, max_iter + 1):
        grid = ring_grid(C, h)
        # the first update queries every point: per-cell candidate lists; later ones query few: rings
        lists = no_lists(p)
        if not have and p <= 3:
            lists = candidate_lists(Xs, np.arange(n, dtype=np.int64), C, grid, K, chunks)
        res = chunks.map(lambda s, t: kf.update_rows(Xs, C, idx, ring, U, reach, hard, have, e, s, t, K, grid, lists,
                                                     flag), n, min_chunk=1024)
        ch = max(r[0] for r in res)
        relabelled = sum(r[1] for r in res)
        tied = np.flatnonzero(flag)
        if len(tied):
            d, i = centre_tree(C).query(Xs[tied], k=K, workers=chunks.threads if len(tied) >= 20_000 else 1)
            c1, c2 = kf.finish_rows(Xs, C, tied, d.reshape(len(tied), K), i.reshape(len(tied), K), idx, ring, U,
                                    reach, hard, have, e)
            ch = max(ch, c1)
            relabelled += c2
        if have and (ch < tol or (label_tol is not None and relabelled <= label_tol * n)):
            conv = True
            break
        have = True
        if it == max_iter:
            break
        num = np.zeros((c, p))
        den = np.zeros(c)
        for bn, bd in chunks.each(lambda s: kf.block_sums(Xs, idx, U, m, s, min(n, s + block), c), range(0, n, block)):
            den += bd
            num += bn
        Cn = C.copy()
        ok = den > 0
        Cn[ok] = num[ok] / den[ok, None]
        reach -= np.sqrt(((Cn - C) ** 2).sum(axis=1)).max()
        C = Cn
    chunks.map(lambda s, t: kf.nearest_first(Xs, C, idx, U, s, t), n)  # nearest first, as documented
    return idx.astype(np.int64), U, C, it, conv
