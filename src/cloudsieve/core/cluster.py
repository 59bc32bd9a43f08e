"""Centroid clustering into many small clusters (DESIGN.md stage 3): shared base and seeding.

:class:`CentroidClustering` is the base of :class:`~.kmeans.KMeans` and
:class:`~.fcm.FuzzyCMeans`, scikit-learn style (fitted state with trailing
underscore; :class:`~cloudsieve.errors.ConvergenceWarning` when ``max_iter`` runs out).

An iteration costs O(n log c): nearest centres come from a grid
(:func:`.centres.nearest_centres`) and K-means skips points by Hamerly's bounds
(:func:`.kmeans.lloyd`). FCM keeps memberships for ``n_nearest`` centres only
(textbook FCM when ``n_nearest >= n_clusters``).

Points are put in lexicographic order before any seeded step, so results do not
depend on input order; the only randomness is ``np.random.default_rng(seed)``.

``init``: "k-means++" (default; on a subsample of ``max(1000, 4 * n_clusters)``
points), "kd-split" (means of a balanced k-d split), "random" (the paper's), or an
array (n_clusters, p).
"""

from __future__ import annotations

import logging
import os
import warnings

import numpy as np

from ._validation import check_points
from .kernels.threads import Chunks
from .kernels import cluster as kcl
from .knn import canonical_order
from ..errors import ConvergenceWarning, InvalidParameterError

__all__ = ["CentroidClustering", "ConvergenceWarning", "INITS", "initial_centres"]

logger = logging.getLogger(__name__)


def _sample(X: np.ndarray, s: int, rng: np.random.Generator) -> np.ndarray:
    """s rows of X uniformly without replacement, in X's order (all when s >= n)."""
    n = len(X)
    return X if s >= n else X[np.sort(rng.choice(n, s, replace=False))]


_PP_BLOCK = 64  # k-means++: points per block of the running D^2 sums


def _kmeanspp(X: np.ndarray, c: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding (one trial per centre) on a uniform subsample of X.

    Exact D^2 sampling over a sample sorted on its first coordinate, with D^2 sums
    kept per block of _PP_BLOCK points, so a draw costs O(s / B + B); compiled in
    :func:`.kernels.cluster.kmeanspp_steps`.
    """
    S = _sample(X, min(len(X), max(1000, 4 * c)), rng)
    S = S[np.argsort(S[:, 0], kind="stable")]
    s, p = S.shape
    B = _PP_BLOCK
    nb = -(-s // B)
    cols = [np.ascontiguousarray(S[:, j]) for j in range(p)]
    d2 = np.full(nb * B, 0.0)  # padded with zeros (never drawn)
    chosen = np.empty(c, dtype=np.int64)
    chosen[0] = rng.integers(s)
    d2[:s] = sum((cols[j] - S[chosen[0], j]) ** 2 for j in range(p))
    bsum = d2.reshape(nb, B).sum(axis=1)
    bmax = d2.reshape(nb, B).max(axis=1)
    k, forced = 1, -1
    while k < c:  # compiled steps; the uniforms drawn ahead, the generator left as if drawn one by one
        state = rng.bit_generator.state
        stop, used = kcl.kmeanspp_steps(S, d2, bsum, bmax, chosen, k, rng.random(c - k), forced, B)
        rng.bit_generator.state = state
        rng.random(used)
        if stop < c:  # every remaining point coincides with a centre
            forced = int(rng.integers(s))
        k = stop
    return S[chosen].copy()


def _kd_split(X: np.ndarray, c: int, rng: np.random.Generator) -> np.ndarray:
    """Centres of a balanced k-d split of a uniform subsample of X (32 points per cluster, >= 10,000).

    Each part is cut across its widest coordinate in proportion to its clusters;
    the centres are the parts' means.
    """
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


def _rows(a, order, threads, kernel):
    """New array: rows of ``a`` taken in ``order`` (``kcl.take_rows``) or put back (``kcl.put_rows``), on threads."""
    out = np.empty_like(a)
    src, dst = a.reshape(len(a), -1), out.reshape(len(a), -1)
    with Chunks(threads) as chunks:
        chunks.map(lambda s, e: kernel(src, order, dst, s, e), len(a), min_chunk=65536)
    return out


INITS = ("k-means++", "random", "kd-split")


def initial_centres(Xs, c, init, rng):
    """Initial centres (c, p) from the canonically ordered points Xs (init "random": each estimator).

    ``init``: "k-means++", "kd-split" or an array_like of shape (c, p).
    """
    if isinstance(init, str) and init == "k-means++":
        return _kmeanspp(Xs, c, rng)
    if isinstance(init, str):
        return _kd_split(Xs, c, rng)
    return np.array(init, dtype=np.float64)


class CentroidClustering:
    """The shared base of :class:`~.kmeans.KMeans` and :class:`~.fcm.FuzzyCMeans`.

    Parameters
    ----------
    n_clusters : int
    init : {"k-means++", "random", "kd-split"} or ndarray of shape (n_clusters, p)
    max_iter : int
    seed : int
    tol : float
        The subclass's stopping tolerance.
    """

    def __init__(self, n_clusters: int, *, init, max_iter: int, seed: int, tol: float):
        self.n_clusters = n_clusters
        self.init = init
        self.max_iter = max_iter
        self.seed = seed
        self.tol = tol

    def fit(self, points, threads: int | None = None):
        """Cluster ``points`` (n, p); returns self. ``threads`` (None: all cores) does not change the result."""
        X = check_points(points)
        self.check_params(*X.shape)
        return self._fit(X, threads)

    def fit_unchecked(self, X: np.ndarray, threads: int | None = None):
        """:meth:`fit` on validated input (:func:`._validation.check_points`, :meth:`check_params`); returns self."""
        return self._fit(X, threads)

    def fit_predict(self, points, threads: int | None = None) -> np.ndarray:
        """Cluster ``points`` and return ``labels_`` (ndarray of shape (n,), int64)."""
        return self.fit(points, threads).labels_

    def check_params(self, n: int, p: int) -> None:
        """Raise :class:`~cloudsieve.errors.InvalidParameterError` unless the parameters fit n points in p dims."""
        n_clusters, max_iter, init = self.n_clusters, self.max_iter, self.init
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
            if a.shape != (n_clusters, p):
                raise InvalidParameterError(
                    f"init centres must have shape ({n_clusters}, {p}), got shape {a.shape}")
        self._check_own_params()

    def _check_own_params(self) -> None:
        """The subclass's own parameters (raises InvalidParameterError)."""

    def _start(self, Xs, c, rng, threads):
        """The initial centres (c, p) from the canonically ordered points Xs."""
        if isinstance(self.init, str) and self.init == "random":
            return self._random_start(Xs, c, rng)
        return initial_centres(Xs, c, self.init, rng)

    def _random_start(self, Xs, c, rng):
        raise NotImplementedError

    def _iterate(self, Xs, C, threads):
        """(labels (n,), centres (c, p), n_iter, converged, {attribute: per-point array (n, ...)})."""
        raise NotImplementedError

    def _unconverged(self, n: int, c: int) -> str:
        raise NotImplementedError

    def _fit(self, X, threads):
        c = int(self.n_clusters)
        threads = int(threads or os.cpu_count() or 1)
        order = canonical_order(X)
        Xs = _rows(X, order, threads, kcl.take_rows)
        rng = np.random.default_rng(self.seed)
        C = self._start(Xs, c, rng, threads)
        labels, C, n_iter, conv, per_point = self._iterate(Xs, C, threads)
        if not conv:  # stacklevel 3: the caller of fit / fit_unchecked
            warnings.warn(self._unconverged(len(X), c), ConvergenceWarning, stacklevel=3)
        self.labels_ = _rows(labels, order, threads, kcl.put_rows)
        for name, a in per_point.items():
            setattr(self, name, _rows(a, order, threads, kcl.put_rows))
        self.cluster_centers_ = C
        self.n_iter_ = n_iter
        self.converged_ = conv
        return self
