"""The rules' entry points on numpy arrays: :func:`prune` and the scores it ranks (DESIGN.md stage 5).

Public functions
----------------
prune(points, labels, *, rule, threshold, ratio, count, score, ...)
    Stages 4-5 for given labels: a keep mask (n,) bool; the rule comes from
    the registry (:func:`cloudsieve.core.rules.get`), its selection from its
    module.
unit_free_scores(points, labels, ...)
    The unit-free score m*dH of every point (m its cluster's size). dH of a
    cluster of m points scales as 1/m, so m*dH is comparable across clusters
    and cells: the engine computes it per cell, picks one global threshold t
    (a quantile of all the scores for --ratio/--count), then keeps the points
    above t in each cell.
threshold_for_count(scores, n_drop)
    The threshold t on given scores such that dropping scores <= t removes
    n_drop points (ties counted), for one cell or a merged sample.
check_rule_args, prune_unchecked
    The kept count a ratio/count asks for, and :func:`prune` on validated
    input (for :func:`~cloudsieve.core.simplify.simplify_points`).
on_distinct
    What every entropy rule shares: canonical order, exact duplicates, labels 0..c-1.

The rules themselves (one module each) are described in :mod:`cloudsieve.core.rules`
and in their modules; the rounds of the rules that take them are in :mod:`..rounds`.

Scores: ``score="delta_h"`` (dH, the paper's S = 0.001) or ``"unit_free"``
(m*dH). Exact duplicates (:mod:`..duplicates`): every rule runs on the
distinct points (the first copy of each, scored once); the other copies go,
or, with ``keep_duplicates``, stay exactly when their first copy stays.
Clusters smaller than k + 2 points score +inf (always kept).

Determinism: inputs are put in a canonical order (lexicographic by
coordinates) first, so the kept set does not depend on input order; it does
not depend on units either (all scores are unit-free).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from .. import rules as registry
from .._validation import check_context, check_labels, check_points, ratio_count
from ..duplicates import sorted_copies
from ..entropy import score_points
from ..knn import canonical_order
from ...params import validate_params
from ...progress import callback

__all__ = ["prune", "unit_free_scores", "threshold_for_count", "check_rule_args", "prune_unchecked", "on_distinct"]

logger = logging.getLogger(__name__)


def unit_free_scores(points, labels=None, *, k0: float = 1.0, k_min: int = 4, dim: float = 3,
                     context=None, threads: int | None = None) -> np.ndarray:
    """m * dH per point (ndarray (n,), float64); +inf in small clusters, 0 for duplicates.

    ``threads``: threads for the k-d tree queries (None: all cores); the scores do not depend on it.
    """
    return score_points(points, labels, k0=k0, k_min=k_min, dim=dim, context=context, threads=threads).unit_free


def threshold_for_count(scores, n_drop: int) -> float:
    """Smallest t with at least ``n_drop`` of ``scores`` <= t (-inf for n_drop <= 0)."""
    s = np.asarray(scores, dtype=np.float64)
    if n_drop <= 0 or len(s) == 0:
        return -math.inf
    n_drop = min(int(n_drop), len(s))
    return float(np.partition(s, n_drop - 1)[n_drop - 1])


@validate_params("prune")
def prune(points, labels=None, *, rule: str = registry.MEMORY_RULE, threshold: float = registry.PAPER_THRESHOLD,
          ratio=None, count=None, score: str = "delta_h", k0: float = 1.0, k_min: int = 4, dim: float = 3,
          context=None, coverage: float = 1.0, max_rounds: int | None = None, progress=None,
          threads: int | None = None, keep_duplicates: bool = False) -> np.ndarray:
    """Apply a pruning rule to clustered points: the keep mask.

    The options are validated once (:func:`cloudsieve.params.validate`, command ``prune``).

    Parameters
    ----------
    points : array_like of shape (n, p), float
    labels : array_like of shape (n,), int, optional
        Clusters (None: one cluster).
    rule : str
        A rule of the registry (:data:`cloudsieve.core.rules.RULES`).
    threshold : float
        S, compared with ``score`` (the rules that take a threshold, without a target).
    ratio, count : float, int, optional
        Kept fraction or kept count (the rules that need or take a target); a
        count above the points keeps them all. The coverage rule may stop short
        of a target when no remaining candidate passes its test (logged).
    score : {"delta_h", "unit_free"}
        Which score S is compared with: dH (the paper) or m*dH.
    coverage : float
        Rule coverage: y may go only if its nearest remaining point is within
        ``coverage`` x (the largest nearest-neighbour spacing among y's k
        nearest), i.e. no gap wider than the local spacing opens.
    progress : callable, optional
        Called with the number of points dropped in each round.
    threads : int, optional
        Threads for the k-d tree queries and the kernels of the rounds (None: all
        cores); the mask does not depend on it.
    keep_duplicates : bool
        False (default): an exact copy of an earlier point (same coordinates,
        lower index) is never kept; a target then counts distinct points and
        may not be met when it exceeds them. True: every copy of a kept point
        is kept too (the rule still sees each point once).

    Returns
    -------
    ndarray of shape (n,), bool
        True for the points kept, in the order of ``points``.

    Notes
    -----
    The points are canonically ordered (lexicographic by coordinates) inside,
    so the mask is the same for any input order.
    """
    pts = check_points(points)
    lab = check_labels(labels, len(pts))
    ctx = check_context(context, pts.shape[1])
    return prune_unchecked(pts, lab, rule=rule, threshold=threshold, target=check_rule_args(len(pts), ratio, count),
                           score=score, k0=k0, k_min=k_min, dim=dim, ctx=ctx, coverage=coverage,
                           max_rounds=max_rounds, progress=progress, threads=threads,
                           keep_duplicates=bool(keep_duplicates))


def check_rule_args(n: int, ratio, count) -> int | None:
    """The kept count of validated *ratio* / *count* for n points (None: no target).

    A ratio keeps :func:`~.._validation.ratio_count` points; a count above n
    keeps the n points (the run reports the count it kept).
    """
    if ratio is not None:
        return ratio_count(ratio, n)
    if count is not None:
        return min(int(count), n)
    return None


def prune_unchecked(pts, lab, *, rule, threshold, target, score, k0, k_min, dim, ctx, coverage, max_rounds,
                    progress, threads, keep_duplicates=False) -> np.ndarray:
    """:func:`prune` on validated input: the keep mask (n,) bool.

    ``pts`` (n, p) float64 and ``lab`` (n,) int64 as from
    :func:`.._validation.check_points` / ``check_labels``, ``target`` from
    :func:`check_rule_args`, ``ctx`` from ``check_context``; no checks, no
    copy of the input. The rule's module selects (:meth:`~cloudsieve.core.rules.Rule.prune`).
    """
    if len(pts) == 0:
        return np.ones(0, dtype=bool)
    return registry.get(rule).prune(pts, lab, threshold=threshold, target=target, score=score, k0=k0, k_min=k_min,
                                    dim=dim, ctx=ctx, coverage=coverage, max_rounds=max_rounds, progress=progress,
                                    threads=threads, keep_duplicates=keep_duplicates)


def on_distinct(select, rule, pts, lab, *, threshold, target, score, k0, k_min, dim, ctx, coverage, max_rounds,
                progress, threads, keep_duplicates) -> np.ndarray:
    """An entropy rule's keep mask (n,): ``select`` runs on the distinct points in canonical order.

    ``select(rule, P, L, threshold=, target=, score=, coverage=, max_rounds=, report=, kw=)`` returns
    the keep mask of the canonically ordered distinct points P (labels L in 0..c-1).
    """
    n = len(pts)
    order = canonical_order(pts)
    P = pts[order]
    L = lab[order]
    copy = sorted_copies(P)
    n_copies = int(copy.sum())
    if n_copies:  # the rule sees each point once; target counts distinct points
        logger.info("%d exact duplicate points %s", n_copies,
                    "kept with their first copy" if keep_duplicates else "removed")
        P, L = P[~copy], L[~copy]
        if target is not None:
            target = min(target, len(P))
    report = callback(progress)
    if n_copies and not keep_duplicates:
        report(n_copies)
    L = np.unique(L, return_inverse=True)[1].reshape(-1).astype(np.int64)  # 0..c-1
    keep_c = select(rule, P, L, threshold=threshold, target=target, score=score, coverage=coverage,
                    max_rounds=max_rounds, report=report, kw=dict(k0=k0, k_min=k_min, dim=dim, ctx=ctx,
                                                                   threads=threads))
    if n_copies:
        first = np.cumsum(~copy) - 1  # each row's distinct point
        keep_c = keep_c[first] if keep_duplicates else np.where(copy, False, keep_c[first])
    out = np.empty(n, dtype=bool)
    out[order] = keep_c
    return out


def ranked(values: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """idx of the finite values, lowest value first (ties: lower idx first)."""
    fin = np.isfinite(values)
    idx = idx[fin]
    o = np.lexsort((idx, values[fin]))
    return idx[o]
