"""The pruning rules (DESIGN.md stage 5): which points of clustered, scored points go.

Public functions
----------------
prune(points, labels, *, rule, threshold, ratio, count, score, ...)
    Stages 4-5 for given labels: a keep mask (n,) bool.
unit_free_scores(points, labels, ...)
    The unit-free score m*dH of every point (m its cluster's size). dH of a
    cluster of m points scales as 1/m, so m*dH is comparable across clusters
    and cells: the engine computes it per cell, picks one global threshold t
    (a quantile of all the scores for --ratio/--count), then calls
    ``prune(..., rule="threshold", threshold=t, score="unit_free")`` per cell.
threshold_for_count(scores, n_drop)
    The threshold t on given scores such that dropping scores <= t removes
    n_drop points (ties counted), for one cell or a merged sample.
check_rule_args, prune_unchecked
    The checks of :func:`prune`'s rule arguments, and :func:`prune` on
    validated input (for :func:`~.simplify.simplify_points`).

The rounds of ``iterative`` and ``coverage`` are in :mod:`.rounds`.

Rules
-----
threshold (the paper)
    One pass: drop every point with score <= S.
iterative (default)
    Rounds. In each, the points with score <= S are candidates, lowest score
    first (ties: canonical order); a candidate is dropped only if no point
    already dropped in this round is one of its k nearest neighbours or has it
    among its own k nearest (so no two points dropped in one round are k-NN
    neighbours, either way). Remaining points are rescored between rounds
    (clusters keep their labels; m and k follow the shrinking cluster); stop
    when no point qualifies. With ``ratio`` or ``count``, every finite score is
    a candidate, on the unit-free score m*dH, and rounds stop when the target
    is met (the last round takes only the lowest candidates it needs).
target
    One pass on the unit-free score: drop the n - target points of lowest
    m*dH (ties: canonical order), so the count is exact.
eliminate (cloudsieve's, issue 12)
    Weighted sample elimination with a coverage term, exactly ``target``
    points kept (:func:`cloudsieve.core.eliminate.eliminate`; its entropy and
    geometric terms are off here, so the labels and scores are not used).
coverage (cloudsieve's, not the paper's)
    ``iterative`` (with S, or with a target) where a candidate y also needs
    r_1(y) <= coverage * median of r_1 over y's k nearest (r_1: distance to
    the nearest remaining point): y may only go where points are at least as
    dense as around it, so no gap wider than the local spacing opens. |dH|
    ranks isolated points (outliers, thin parts, borders) as the most
    redundant; this rule keeps them. Measured in benchmarks/quality.py: at 50%
    kept it lowers the point RMS error of ``iterative`` by 16-41% on
    bun_zipper, maxplanck and autzen_trim (and the max error by 2-4x).

Scores: ``score="delta_h"`` (dH, the paper's S = 0.001) or ``"unit_free"``
(m*dH). Exact duplicates (:mod:`.duplicates`): every rule runs on the
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

from ._validation import check_context, check_density_params, check_labels, check_points, ratio_count
from .duplicates import copy_rows, first_rows, sorted_copies
from .eliminate import eliminate
from .entropy import score_points, score_unchecked
from .knn import canonical_order
from .rounds import prune_in_rounds
from ..errors import InvalidParameterError
from ..progress import callback

__all__ = ["RULES", "PAPER_THRESHOLD", "prune", "unit_free_scores", "threshold_for_count", "check_rule_args", "prune_unchecked"]

logger = logging.getLogger(__name__)

RULES = ("iterative", "threshold", "target", "coverage", "eliminate")
#: S of the paper (Mahdaoui et al. 2017): the threshold of the rules threshold and iterative when none is given
PAPER_THRESHOLD = 1e-3


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


def _target_count(n, ratio, count):
    if ratio is not None and count is not None:
        raise InvalidParameterError(f"give ratio or count, not both (ratio={ratio!r}, count={count!r})")
    if ratio is not None:
        if not (0 <= ratio <= 1):
            raise InvalidParameterError(f"ratio is the kept fraction, in [0, 1], got {ratio!r}")
        return ratio_count(ratio, n)
    if count is not None:
        if int(count) != count or count < 0:
            raise InvalidParameterError(f"count must be an integer >= 0, got {count!r}")
        return min(int(count), n)
    return None


def prune(points, labels=None, *, rule: str = "iterative", threshold: float = PAPER_THRESHOLD, ratio=None, count=None,
          score: str = "delta_h", k0: float = 1.0, k_min: int = 4, dim: float = 3, context=None,
          coverage: float = 1.0, max_rounds: int | None = None, progress=None,
          threads: int | None = None, keep_duplicates: bool = False) -> np.ndarray:
    """Apply a pruning rule to clustered points: the keep mask.

    Parameters
    ----------
    points : array_like of shape (n, p), float
    labels : array_like of shape (n,), int, optional
        Clusters (None: one cluster).
    rule : {"iterative", "threshold", "target", "coverage", "eliminate"}
    threshold : float
        S, compared with ``score`` (rules threshold and iterative without a target).
    ratio, count : float, int, optional
        Kept fraction or kept count (rules target and eliminate; iterative/coverage with a target).
        The coverage rule may stop short of a target when no remaining
        candidate passes its test (logged).
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
    check_density_params(k0, k_min, dim)
    target = check_rule_args(len(pts), rule, threshold, ratio, count, score)
    ctx = check_context(context, pts.shape[1])
    return prune_unchecked(pts, lab, rule=rule, threshold=threshold, target=target, score=score, k0=k0,
                           k_min=k_min, dim=dim, ctx=ctx, coverage=coverage, max_rounds=max_rounds,
                           progress=progress, threads=threads, keep_duplicates=bool(keep_duplicates))


def check_rule_args(n: int, rule, threshold, ratio, count, score) -> int | None:
    """Check the rule arguments of :func:`prune` for n points; return the kept count it targets (None: none).

    Raises
    ------
    InvalidParameterError
        An unknown rule or score, a bad ratio or count (or both given), a
        target rule without one or the threshold rule with one, a non-finite
        threshold.
    """
    if rule not in RULES:
        raise InvalidParameterError(f"rule must be one of {', '.join(RULES)}, got {rule!r}")
    if score not in ("delta_h", "unit_free"):
        raise InvalidParameterError(f"score must be 'delta_h' or 'unit_free', got {score!r}")
    target = _target_count(n, ratio, count)
    if rule in ("target", "eliminate") and target is None:
        raise InvalidParameterError(f"rule={rule!r} needs ratio= (kept fraction) or count= (kept points)")
    if rule == "threshold" and target is not None:
        raise InvalidParameterError(
            f"rule='threshold' takes threshold= only, not ratio={ratio!r}/count={count!r}: use rule='target'")
    if not np.isfinite(threshold):
        raise InvalidParameterError(f"threshold must be finite, got {threshold!r}")
    return target


def prune_unchecked(pts, lab, *, rule, threshold, target, score, k0, k_min, dim, ctx, coverage, max_rounds,
                    progress, threads, keep_duplicates=False) -> np.ndarray:
    """:func:`prune` on validated input: the keep mask (n,) bool.

    ``pts`` (n, p) float64 and ``lab`` (n,) int64 as from
    :func:`._validation.check_points` / ``check_labels``, ``target`` from
    :func:`check_rule_args`, ``ctx`` from ``check_context``; no checks, no
    copy of the input. The rule runs on the distinct points only
    (:mod:`.duplicates`).
    """
    n = len(pts)
    keep = np.ones(n, dtype=bool)
    if n == 0:
        return keep
    if rule == "eliminate":  # no labels, no scores; exact copies go first (priority +inf) and never weigh
        keep[:] = False
        target = min(target, n - int(copy_rows(pts).sum()))  # copies kept at most once
        keep[eliminate(pts, count=target, threads=threads)] = True
        if keep_duplicates:  # every copy of a kept point (the first copy is the one the elimination may keep)
            keep = keep[first_rows(pts)]
        callback(progress)(n - int(keep.sum()))
        return keep
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
    keep_c = _rule_mask(P, L, rule, threshold, target, score, coverage, max_rounds, report,
                        dict(k0=k0, k_min=k_min, dim=dim, ctx=ctx, threads=threads))
    if n_copies:
        first = np.cumsum(~copy) - 1  # each row's distinct point
        keep_c = keep_c[first] if keep_duplicates else np.where(copy, False, keep_c[first])
    out = np.empty(n, dtype=bool)
    out[order] = keep_c
    return out


def _rule_mask(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw) -> np.ndarray:
    """The keep mask (n,) of the rule on canonically ordered points P (labels L, any ints)."""
    n = len(P)
    L = np.unique(L, return_inverse=True)[1].reshape(-1).astype(np.int64)  # 0..c-1

    if rule == "threshold":
        s = score_unchecked(P, L, **kw)
        val = s.delta_h if score == "delta_h" else s.unit_free
        keep_c = ~(val <= threshold)
        report(int((~keep_c).sum()))
    elif rule == "target":
        s = score_unchecked(P, L, **kw)
        n_drop = n - target
        cand = _ranked(s.unit_free, np.arange(n))
        drop = cand[:n_drop]
        if len(drop) < n_drop:
            logger.warning("target of %d points unreachable: only %d points have a finite score; kept %d",
                           target, len(cand), n - len(drop))
        keep_c = np.ones(n, dtype=bool)
        keep_c[drop] = False
        report(len(drop))
    else:
        keep_c = prune_in_rounds(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw)
    return keep_c


def _ranked(values: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """idx of the finite values, lowest value first (ties: lower idx first)."""
    v = values
    fin = np.isfinite(v)
    idx = idx[fin]
    o = np.lexsort((idx, v[fin]))
    return idx[o]
