"""Centroid clustering into many small clusters (DESIGN.md stage 3): the shared base and the seeding.

:class:`CentroidClustering` is the base of :class:`~.kmeans.KMeans` and
:class:`~.fcm.FuzzyCMeans` (like scikit-learn's ``_BaseKMeans``): parameters
in ``__init__``, work in ``fit``, fitted state with a trailing underscore, one
``seed``, and a :class:`~cloudsieve.errors.ConvergenceWarning` when
``max_iter`` runs out.

Cost per iteration is O(n log c), not O(n c): nearest centres come from a
uniform grid over the centres (:func:`.centres.nearest_centres`, compiled,
the same answer as scipy's ``cKDTree``), and K-means skips the points whose
assignment provably cannot change (Hamerly's bounds, with the lower bound decaying by the largest move
among each centre's K nearest centres rather than among all; see
:func:`.kmeans.lloyd`). Fuzzy C-means keeps each point's memberships for its
``n_nearest`` nearest centres only (all others are zero); with ``n_nearest >=
n_clusters`` this is exactly the textbook (dense) FCM.

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

    Exact D^2 sampling, written by hand (scikit-learn's is O(s c) per run and
    would add a dependency): the sample is sorted on its first coordinate, so a
    new centre x0 can only lower D^2 of the points within sqrt(max D^2) of x0
    along that axis, a window found by binary search; sums and maxima of D^2
    are kept per block of _PP_BLOCK points, so a draw costs O(s / B + B) and an
    update O(window + s / B) instead of O(s). The steps are compiled
    (:func:`.kernels.cluster.kmeanspp_steps`), with the same draws and sums."""
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


def _rows(a, order, threads, kernel):
    """A new array: the rows of ``a`` (n, ...) taken in ``order`` (``kcl.take_rows``:
    ``a[order]``) or put back from it (``kcl.put_rows``: ``out[order] = a``), on threads."""
    out = np.empty_like(a)
    src, dst = a.reshape(len(a), -1), out.reshape(len(a), -1)
    with Chunks(threads) as chunks:
        chunks.map(lambda s, e: kernel(src, order, dst, s, e), len(a), min_chunk=65536)
    return out


INITS = ("k-means++", "random", "kd-split")


def initial_centres(Xs, c, init, rng):
    """Centres to start from, ndarray of shape (c, p) (init "random" is handled by each estimator).

    Parameters
    ----------
    Xs : ndarray of shape (n, p), float64
        The points in canonical order.
    c : int
    init : {"k-means++", "kd-split"} or array_like of shape (c, p)
    rng : numpy.random.Generator
    """
    if isinstance(init, str) and init == "k-means++":
        return _kmeanspp(Xs, c, rng)
    if isinstance(init, str):
        return _kd_split(Xs, c, rng)
    return np.array(init, dtype=np.float64)


class CentroidClustering:
    """The shared base of :class:`~.kmeans.KMeans` and :class:`~.fcm.FuzzyCMeans`.

    Holds the common parameters, validates them against the input
    (:meth:`check_params`), puts the points in canonical order, seeds, runs
    the subclass's iterations (``_iterate``), warns when they ran out, and
    maps the fitted per-point state back to the input order.

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
        """Cluster ``points`` (array_like of shape (n, p)); returns self.

        ``threads``: threads of the compiled passes over the points (None: all cores); the result
        does not depend on it.
        """
        X = check_points(points)
        self.check_params(*X.shape)
        return self._fit(X, threads)

    def fit_unchecked(self, X: np.ndarray, threads: int | None = None):
        """:meth:`fit` on validated input: ``X`` from :func:`._validation.check_points` and
        :meth:`check_params` passed for its shape (no checks, no copy); returns self."""
        return self._fit(X, threads)

    def fit_predict(self, points, threads: int | None = None) -> np.ndarray:
        """Cluster ``points`` and return ``labels_`` (ndarray of shape (n,), int64)."""
        return self.fit(points, threads).labels_

    def check_params(self, n: int, p: int) -> None:
        """Raise :class:`~cloudsieve.errors.InvalidParameterError` unless the
        parameters fit an input of n points in p dimensions."""
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
