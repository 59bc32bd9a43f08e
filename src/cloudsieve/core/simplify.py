"""The method in memory, end to end (DESIGN.md stages 3-5): refine, score, prune.

:func:`simplify_points` validates its options once (:func:`cloudsieve.params.validate_params`,
command ``simplify_points``) and its arrays (:mod:`._validation`), then runs the stages'
kernels on the validated arrays: :func:`.refine.refine_unchecked` (KM or FCM
labels, unless ``labels`` are given) and :func:`.rules.prune_unchecked`
(scores and the rule).
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
        Refinement into c = ceil(n / cluster_size) clusters (ignored when
        ``labels`` is given).
    rule : str
        A rule of the registry (:data:`.rules.RULES`; default ``iterative``).
        ``eliminate`` needs no clusters: ``method``,
        ``labels`` and the entropy options are then unused (no KM/FCM runs);
        it keeps what :func:`cloudsieve.simplify` keeps with the same
        ``seed``, ``cluster_size``, ``k0`` and ``k_min`` (the engine's cells:
        :mod:`cloudsieve.engine.cell_scheme`).
        The default stays ``iterative`` here (the paper's in-memory method,
        which needs no ratio or count), while :func:`cloudsieve.simplify`,
        :func:`cloudsieve.compare`, the CLI and the pipelines default to
        ``eliminate`` (it needs ``ratio`` or ``count``; see
        :mod:`cloudsieve.params`).
    threshold : float
        S on dH (0.001, the paper: :data:`.rules.PAPER_THRESHOLD`).
    ratio, count : optional
        Kept fraction in (0, 1] / kept count >= 1 (the rules that need or take a target);
        a count above the points keeps them all (the returned indices say how many).
    cluster_size : int
        >= k_min + 2.
    seed : int
    k0, k_min : float, int
    context : array_like of shape (q, 3), optional
        Extra density neighbours, never removed.
    labels : array_like of shape (n,), int, optional
        Use these clusters instead of refining.
    threads : int, optional
        Threads for the k-d tree queries of clustering and scoring and for the
        kernels of the rounds (None: all cores); the result does not depend on it.
    keep_duplicates : bool
        Keep every exact copy of a kept point (default: an exact duplicate
        of an earlier point is never kept, with ``eliminate`` unless the
        distinct points do not make the count; see :mod:`.duplicates`).

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

    ``pts`` (n, 3) float64 and ``labels`` (n,) int64 or None as from :mod:`._validation`;
    ``options`` the frozen options object of ``simplify_points``
    (:data:`cloudsieve.params_spec.OPTION_CLASSES`; its ratio and count unread);
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
