"""The rules' entry points on numpy arrays: :func:`prune` and its scores (DESIGN.md stage 5).

- :func:`prune`: stages 4-5 for given labels, a keep mask; the rule comes from
  :func:`cloudsieve.core.rules.get`.
- :func:`unit_free_scores`: m*dH per point, comparable across clusters and cells
  (dH scales as 1/m), so the engine picks one global threshold.
- :func:`threshold_for_count`: the threshold that drops n_drop points.
- :func:`check_rule_args`, :func:`prune_unchecked`: for :func:`~cloudsieve.core.simplify.simplify_points`.

Shared by every entropy rule (canonical order, duplicates, labels 0..c-1):
:func:`.distinct.on_distinct`; rounds: :mod:`..rounds`. The kept set depends on
neither input order nor units.
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
    """m * dH per point (ndarray (n,), float64); +inf in small clusters, 0 for duplicates. ``threads`` None: all cores."""
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

    Options are validated once (:func:`cloudsieve.params.validate`, command ``prune``).

    Parameters
    ----------
    points : array_like of shape (n, p), float
    labels : array_like of shape (n,), int, optional
        Clusters (None: one cluster).
    rule : str
        A rule of :data:`cloudsieve.core.rules.RULES`.
    threshold : float
        S, compared with ``score`` (rules that take a threshold, without a target).
    ratio, count : float, int, optional
        Kept fraction or count; a count above n keeps all. The coverage rule may stop
        short of a target when no candidate passes its test (logged).
    score : {"delta_h", "unit_free"}
        dH (the paper) or m*dH.
    coverage : float
        Rule coverage: y may go only if r_1(y) <= ``coverage`` x the median r_1 of its
        k nearest (:mod:`.coverage`).
    progress : callable, optional
        Called with the points dropped in each round.
    threads : int, optional
        None: all cores; the mask does not depend on it.
    keep_duplicates : bool
        False: exact copies of a lower-index point are never kept (a target counts
        distinct points). True: every copy of a kept point is kept.

    Returns
    -------
    ndarray of shape (n,), bool
        True for the points kept, in the order of ``points``; independent of input order.
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
    """The kept count of validated *ratio* / *count* for n points (None: no target; ratio via :func:`~.._validation.ratio_count`)."""
    if ratio is not None:
        return ratio_count(ratio, n)
    if count is not None:
        return min(int(count), n)
    return None


def prune_unchecked(pts, lab, options, *, target, ctx=None, progress=None) -> np.ndarray:
    """:func:`prune` on validated input (no checks, no copy): the keep mask (n,) bool.

    ``options``: frozen options of ``prune`` (:data:`cloudsieve.params_spec.OPTION_CLASSES`),
    ``target`` from :func:`check_rule_args`; the rule's module
    (:attr:`cloudsieve.rule_table.Rule.module`) selects.
    """
    if len(pts) == 0:
        return np.ones(0, dtype=bool)
    chosen = registry.get(options.rule)
    return import_module(chosen.module, __package__).prune(chosen, pts, lab, options, target=target, ctx=ctx,
                                                           progress=progress)
