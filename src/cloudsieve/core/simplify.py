"""The method in memory, end to end (DESIGN.md stages 3-5): refine, score, prune.

Options are validated once (:func:`cloudsieve.params.validate_params`), arrays by
:mod:`._validation`; then :func:`.refine.refine_unchecked` and :func:`.rules.prune_unchecked`.
"""

from __future__ import annotations

import numpy as np

from . import rules
from ._validation import check_context, check_labels, check_points
from ..params import validate_params
from ..params_spec import OPTION_CLASSES

__all__ = ["simplify_points", "simplify_unchecked"]


@validate_params("simplify_points")
def simplify_points(points, *, method: str = "km", rule: str = rules.MEMORY_RULE,
                    threshold: float = rules.PAPER_THRESHOLD,
                    ratio=None, count=None, cluster_size: int = 400, seed: int = 0, k0: float = 1.0,
                    k_min: int = 4, context=None, labels=None, score: str = "delta_h",
                    n_nearest: int = 8, init="k-means++", coverage: float = 1.0,
                    progress=None, threads: int | None = None, keep_duplicates: bool = False) -> np.ndarray:
    """Simplify a cloud in memory: refine into clusters, score, prune.

    Parameters
    ----------
    points : array_like of shape (n, 3), float
    method : {"km", "fcm"}
        Refinement into c = ceil(n / cluster_size) clusters (ignored with ``labels``).
    rule : str
        A rule of :data:`.rules.RULES`; default ``iterative`` (the paper's), while
        :func:`cloudsieve.simplify`, :func:`cloudsieve.compare` and the CLI default to
        ``eliminate``, which needs no clusters and keeps what :func:`cloudsieve.simplify`
        keeps with the same ``seed``, ``cluster_size``, ``k0`` and ``k_min``.
    threshold : float
        S on dH (:data:`.rules.PAPER_THRESHOLD`).
    ratio, count : optional
        Kept fraction in (0, 1] / kept count >= 1; a count above n keeps all.
    cluster_size : int
        >= k_min + 2.
    seed, k0, k_min : int, float, int
    context : array_like of shape (q, 3), optional
        Extra density neighbours, never removed.
    labels : array_like of shape (n,), int, optional
        Use these clusters instead of refining.
    threads : int, optional
        None: all cores; the result does not depend on it.
    keep_duplicates : bool
        Keep every exact copy of a kept point (:mod:`.duplicates`).

    Returns
    -------
    ndarray of shape (n_kept,), int64
        Indices of the kept points, ascending.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).random((2000, 3))
    >>> kept = simplify_points(pts, method="km", rule="target", ratio=0.5)
    >>> len(kept)
    1000
    """
    pts = check_points(points)
    n, p = pts.shape
    lab = None if labels is None else check_labels(labels, n)
    ctx = check_context(context, p)
    options = OPTION_CLASSES["simplify_points"](
        method=method, rule=rule, threshold=threshold, ratio=ratio, count=count, cluster_size=cluster_size, seed=seed,
        k0=k0, k_min=k_min, keep_duplicates=bool(keep_duplicates), score=score, n_nearest=n_nearest,
        coverage=coverage, threads=threads)
    return simplify_unchecked(pts, options, target=rules.check_rule_args(n, ratio, count), ctx=ctx, labels=lab,
                              init=init, progress=progress)


def simplify_unchecked(pts, options, *, target, ctx=None, labels=None, init="k-means++", progress=None) -> np.ndarray:
    """:func:`simplify_points` on validated input (the engine's cells call it): kept indices, ascending.

    ``options``: frozen options of ``simplify_points`` (:data:`cloudsieve.params_spec.OPTION_CLASSES`);
    ``target`` the kept count (None: the threshold decides); no checks.
    """
    from .knn import canonical_order
    from .refine import make_estimator, refine_unchecked

    o = options
    method, rule, cluster_size, seed, k_min, threads = o.method, o.rule, o.cluster_size, o.seed, o.k_min, o.threads
    n = len(pts)
    if rules.get(rule).engine == rules.ELIMINATION and n:  # the engine's cells, with this seed and cluster size
        from .rules.eliminate import select

        keep = select(pts, target=target, seed=seed, cluster_size=cluster_size, k0=o.k0, k_min=k_min, progress=progress,
                      keep_duplicates=bool(o.keep_duplicates))
        return np.flatnonzero(keep).astype(np.int64)
    if not rules.get(rule).clusters:  # e.g. weighted sample elimination: no clusters needed
        lab = np.zeros(n, dtype=np.int64)
    elif labels is None:
        est = make_estimator(pts.shape, method, cluster_size, seed, k_min=k_min, n_nearest=o.n_nearest, init=init)
        order = canonical_order(pts)
        lab_c = refine_unchecked(pts[order], est, threads)
        lab = np.empty(n, dtype=np.int64)
        lab[order] = lab_c
    else:
        lab = labels
    pruning = OPTION_CLASSES["prune"](rule=rule, threshold=o.threshold, score=o.score, k0=o.k0, k_min=k_min, dim=3,
                                      coverage=o.coverage, max_rounds=None, threads=threads,
                                      keep_duplicates=bool(o.keep_duplicates))
    keep = rules.prune_unchecked(pts, lab, pruning, target=target, ctx=ctx, progress=progress)
    return np.flatnonzero(keep).astype(np.int64)
