"""Refinement into small clusters (DESIGN.md stage 3): K-means or fuzzy C-means labels.

:func:`refine_labels` (checked; the engine calls it per cell), :func:`make_estimator`,
and :func:`refine_unchecked` on validated points (for :func:`~.simplify.simplify_points`).
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

# The refinement's stopping rule: sooner than the paper's (KM: no point changes; FCM:
# memberships move < 1e-5), same point RMS in far fewer iterations (docs/architecture.md,
# "The refinement stops early by default"). KMeans and FuzzyCMeans keep the paper's criteria.
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
        Default: 300 for KM, ``REFINE_FCM_MAX_ITER`` for FCM.
    tol : float, optional
        KM: stop when at most ``tol * n`` points changed cluster (default ``REFINE_KM_TOL``;
        0: the paper's). FCM: largest membership change (default 1e-5, the paper's).
    label_tol : float or None
        FCM only: also stop when at most ``label_tol * n`` hard labels changed
        (default ``REFINE_LABEL_TOL``); None: the paper's test alone.
    threads : int, optional
        None: all cores; the labels do not depend on it.

    Returns
    -------
    ndarray of shape (n,), int64
        Labels in 0..c-1 (some may be unused).

    Notes
    -----
    ``tol=0, max_iter=300`` gives the paper's KM, ``max_iter=300, label_tol=None`` its
    FCM. Hitting ``max_iter`` is logged at INFO level instead of a
    :class:`~cloudsieve.errors.ConvergenceWarning`: the labels are still a valid partition.
    """
    pts = check_points(points)
    est = make_estimator(pts.shape, method, cluster_size, seed, k_min=k_min, n_nearest=n_nearest,
                         max_iter=max_iter, init=init, tol=tol, label_tol=label_tol)
    return refine_unchecked(pts, est, threads)


def make_estimator(shape, method: str, cluster_size: int, seed: int, *, k_min: int = 4, n_nearest: int = 8,
                   max_iter: int | None = None, init="k-means++", tol: float | None = None,
                   label_tol: float | None = REFINE_LABEL_TOL) -> CentroidClustering | None:
    """The refinement's estimator of c = ceil(n / cluster_size) clusters for ``shape`` (n, p); None when n = 0.

    Parameters as :func:`refine_labels` (method and cluster_size already valid).

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
    """Labels (n,) int64 of ``est`` fitted to validated ``pts``; a ConvergenceWarning is logged at INFO instead."""
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
