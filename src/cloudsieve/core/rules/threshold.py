"""Rule threshold (the paper's): one pass, drop every point whose score is <= S."""

from __future__ import annotations

import numpy as np

__all__ = ["prune"]


def prune(rule, pts, lab, options, **kw) -> np.ndarray:
    """The keep mask (n,) bool: the distinct points whose score (dH, or m*dH) is > S."""
    from .distinct import on_distinct

    return on_distinct(_select, rule.name, pts, lab, options, **kw)


def _select(rule, P, L, *, threshold, target, score, coverage, max_rounds, report, kw) -> np.ndarray:
    from ..entropy import score_unchecked

    s = score_unchecked(P, L, **kw)
    val = s.delta_h if score == "delta_h" else s.unit_free
    keep = ~(val <= threshold)
    report(int((~keep).sum()))
    return keep
