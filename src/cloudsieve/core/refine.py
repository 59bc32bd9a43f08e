"""Refinement into small clusters (DESIGN.md stage 3): K-means or fuzzy C-means labels.

:func:`refine_labels` clusters n points into c = ceil(n / cluster_size)
clusters with :class:`~.kmeans.KMeans` or :class:`~.fcm.FuzzyCMeans` (the
engine calls it per cell; it checks its arguments); :func:`make_estimator` builds the estimator and
:func:`refine_unchecked` runs it on validated points (for
:func:`~.simplify.simplify_points`).
"""

from __future__ import annotations

import logging
import math
import warnings

import numpy as np

from ._validation import check_points
from .cluster import CentroidClustering
from .fcm import FuzzyCMeans
from .kmeans import KMeans
from ..errors import ConvergenceWarning
from ..params import validate_params
from ..params_spec import METHODS as _METHODS

__all__ = ["METHODS", "REFINE_LABEL_TOL", "REFINE_KM_TOL", "REFINE_FCM_MAX_ITER", "refine_labels",
           "make_estimator", "refine_unchecked"]

logger = logging.getLogger(__name__)

METHODS = _METHODS  # the option's choices (:mod:`cloudsieve.params_spec`)

# The refinement's stopping rule. The paper runs KM until no point changes
# cluster and FCM until memberships move less than 1e-5. Measured (1 M points
# into 2,500 clusters): KM needs 225 iterations to "no change" but
# 16 to "at most 1% changed", at the same mean squared error within 2.3%; and
# simplify_points(rule=iterative, ratio=0.5) then gives the same point RMS
# (bun_zipper 0.3668% vs 0.3656% of the diagonal, maxplanck 0.4528% vs
# 0.4504%). FCM never reaches 1e-5 in 300 iterations on the real scans, and 20
# iterations give the same RMS as 300 on bun_zipper (0.3667% vs 0.3687%).
# FCM also stops at the KM test, at most 1% of the hard labels
# changed in an update, which it reaches after 7-11 updates (bun_zipper, a
# 100 k-point surface). Point RMS after iterative to 50%, 20 updates vs this
# stop: bun_zipper 0.3667% vs 0.3655%, maxplanck 0.4519% vs 0.4506%,
# autzen_trim 0.1737% vs 0.1720%, in about half the refinement's time.
# KMeans/FuzzyCMeans keep the paper's criteria as their own defaults.
REFINE_LABEL_TOL = 0.01
REFINE_KM_TOL = REFINE_LABEL_TOL
REFINE_FCM_MAX_ITER = 20


@validate_params("refine")
def refine_labels(points, method: str = "km", cluster_size: int = 400, seed: int = 0, *,
                  k_min: int = 4, n_nearest: int = 8, max_iter: int | None = None, init="k-means++",
                  threads: int | None = None, tol: float | None = None,
                  label_tol: float | None = REFINE_LABEL_TOL) -> np.ndarray:
    """Cluster labels of KM or FCM into c = ceil(n / cluster_size) clusters.

    Parameters
    ----------
    points : array_like of shape (n, p), float
    method : {"km", "fcm"}
    cluster_size : int
        Mean points per cluster, >= k_min + 2.
    seed : int
    max_iter : int, optional
        Default: 300 for KM, ``REFINE_FCM_MAX_ITER`` (20) for FCM.
    tol : float, optional
        KM: stop when at most ``tol * n`` points changed cluster (default
        ``REFINE_KM_TOL`` = 0.01; 0 is the paper's "no point changes").
        FCM: the largest membership change (default 1e-5, the paper's).
    label_tol : float or None
        FCM only: also stop when at most ``label_tol * n`` hard labels changed
        in an update (default ``REFINE_LABEL_TOL`` = 0.01, KM's default test);
        None for the paper's membership test alone.
    threads : int, optional
        Threads of the refinement's compiled passes (None: all cores). The labels do not
        depend on it.

    Returns
    -------
    ndarray of shape (n,), int64
        Labels in 0..c-1 (some may be unused when a cluster empties).

    Notes
    -----
    The defaults stop earlier than the paper (see ``REFINE_LABEL_TOL`` for the
    measurements); ``tol=0, max_iter=300`` gives the paper's KM and
    ``max_iter=300, label_tol=None`` the paper's FCM. Hitting
    ``max_iter`` (usual for FCM at tol=1e-5 on large uniform surfaces) is logged at INFO level instead of raising a
    :class:`~cloudsieve.errors.ConvergenceWarning`: the labels still form a
    valid partition into small clusters.
    """
    pts = check_points(points)
    est = make_estimator(pts.shape, method, cluster_size, seed, k_min=k_min, n_nearest=n_nearest,
                         max_iter=max_iter, init=init, tol=tol, label_tol=label_tol)
    return refine_unchecked(pts, est, threads)


def make_estimator(shape, method: str, cluster_size: int, seed: int, *, k_min: int = 4, n_nearest: int = 8,
                   max_iter: int | None = None, init="k-means++", tol: float | None = None,
                   label_tol: float | None = REFINE_LABEL_TOL) -> CentroidClustering | None:
    """The refinement's estimator for points of shape (n, p) (method and cluster_size already valid).

    Parameters are those of :func:`refine_labels`; ``shape`` is (n, p).

    Returns
    -------
    KMeans, FuzzyCMeans or None
        The estimator of c = ceil(n / cluster_size) clusters, its parameters
        checked against the shape; None when n = 0 (nothing to cluster).

    Raises
    ------
    InvalidParameterError
        A bad estimator parameter.
    """
    n, p = shape
    if n == 0:
        return None
    c = max(1, math.ceil(n / cluster_size))
    if method == "km":
        est = KMeans(c, init=init, max_iter=300 if max_iter is None else max_iter, seed=seed,
                     tol=REFINE_KM_TOL if tol is None else tol)
    else:
        est = FuzzyCMeans(c, n_nearest=n_nearest, init=init, seed=seed,
                          max_iter=REFINE_FCM_MAX_ITER if max_iter is None else max_iter,
                          tol=1e-5 if tol is None else tol, label_tol=label_tol)
    est.check_params(n, p)
    return est


def refine_unchecked(pts: np.ndarray, est: CentroidClustering | None, threads: int | None) -> np.ndarray:
    """Labels (n,) int64 of ``est`` (from :func:`make_estimator` for this shape) fitted to validated ``pts``.

    A :class:`~cloudsieve.errors.ConvergenceWarning` is logged at INFO level
    instead (see :func:`refine_labels`); other warnings pass through.
    """
    if est is None:
        return np.zeros(0, dtype=np.int64)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        labels = est.fit_unchecked(pts, threads=threads).labels_
    for w in caught:  # a refinement that ran out of iterations is still a partition: log, don't warn
        if issubclass(w.category, ConvergenceWarning):
            logger.info("%s", w.message)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return labels
