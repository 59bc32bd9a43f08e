"""Rule target: a ratio or a count instead of S; one pass on the unit-free score.

Drops the n - target points of lowest m*dH (ties: canonical order); out of core,
one global threshold (:mod:`cloudsieve.engine.threshold`).
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = ["prune"]

logger = logging.getLogger(__name__)


def prune(rule, pts, lab, options, **kw) -> np.ndarray:
    """The keep mask (n,) bool: all but the n - target distinct points of lowest m*dH."""
    from .distinct import on_distinct

    return on_distinct(_select, rule.name, pts, lab, options, **kw)


def _select(rule, P, L, *, threshold, target, score, coverage, max_rounds, report, kw) -> np.ndarray:
    from ..entropy import score_unchecked
    from .distinct import ranked

    n = len(P)
    s = score_unchecked(P, L, **kw)
    n_drop = n - target
    cand = ranked(s.unit_free, np.arange(n))
    drop = cand[:n_drop]
    if len(drop) < n_drop:
        logger.warning("target of %d points unreachable: only %d points have a finite score; kept %d",
                       target, len(cand), n - len(drop))
    keep = np.ones(n, dtype=bool)
    keep[drop] = False
    report(len(drop))
    return keep
