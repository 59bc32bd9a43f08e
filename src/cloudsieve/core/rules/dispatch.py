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

What every entropy rule shares (canonical order, exact duplicates, labels
0..c-1) is :func:`.distinct.on_distinct`.

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

import math
from importlib import import_module

import numpy as np

from .._validation import check_context, check_labels, check_points, ratio_count
from ..entropy import score_points
from ... import rule_table as registry
from ...params import validate_params
from ...params_spec import OPTION_CLASSES

__all__ = ["prune", "unit_free_scores", "threshold_for_count", "check_rule_args", "prune_unchecked"]


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
    options = OPTION_CLASSES["prune"](rule=rule, threshold=threshold, ratio=ratio, count=count, score=score, k0=k0,
                                      k_min=k_min, dim=dim, coverage=coverage, max_rounds=max_rounds,
                                      threads=threads, keep_duplicates=bool(keep_duplicates))
    return prune_unchecked(pts, lab, options, target=check_rule_args(len(pts), ratio, count), ctx=ctx,
                           progress=progress)


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


def prune_unchecked(pts, lab, options, *, target, ctx=None, progress=None) -> np.ndarray:
    """:func:`prune` on validated input: the keep mask (n,) bool.

    ``pts`` (n, p) float64 and ``lab`` (n,) int64 as from
    :func:`.._validation.check_points` / ``check_labels``, ``options`` the
    frozen options of ``prune`` (:data:`cloudsieve.params_spec.OPTION_CLASSES`;
    its ratio and count unread), ``target`` from :func:`check_rule_args`,
    ``ctx`` from ``check_context``; no checks, no copy of the input. The rule's module (:attr:`cloudsieve.rule_table.Rule.module`, loaded by name) selects.
    """
    if len(pts) == 0:
        return np.ones(0, dtype=bool)
    chosen = registry.get(options.rule)
    return import_module(chosen.module, __package__).prune(chosen, pts, lab, options, target=target, ctx=ctx,
                                                           progress=progress)
