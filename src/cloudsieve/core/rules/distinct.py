"""What every entropy rule's selection shares: canonical order, exact duplicates, labels 0..c-1, ranking.

Imports no rule module nor :mod:`.dispatch`.
"""

from __future__ import annotations

import logging

import numpy as np

from ..duplicates import sorted_copies
from ..knn import canonical_order
from ...progress import callback

__all__ = ["on_distinct", "ranked"]

logger = logging.getLogger(__name__)


def on_distinct(select, rule, pts, lab, options, *, target, ctx, progress) -> np.ndarray:
    """An entropy rule's keep mask (n,): ``select`` runs on the distinct points in canonical order.

    ``options``: the frozen options of ``prune``. ``select(rule, P, L, threshold=, target=,
    score=, coverage=, max_rounds=, report=, kw=)`` returns the keep mask of P (labels 0..c-1).
    """
    keep_duplicates = options.keep_duplicates
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
    keep_c = select(rule, P, L, threshold=options.threshold, target=target, score=options.score,
                    coverage=options.coverage, max_rounds=options.max_rounds, report=report,
                    kw=dict(k0=options.k0, k_min=options.k_min, dim=options.dim, ctx=ctx, threads=options.threads))
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
