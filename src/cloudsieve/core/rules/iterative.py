"""Rule iterative: the paper's test in rounds (:mod:`cloudsieve.core.rounds`).

In each round, the points with score <= S are candidates, lowest score first
(ties: canonical order); a candidate is dropped only if no point already
dropped in this round is one of its k nearest neighbours or has it among its
own k nearest (so no two points dropped in one round are k-NN neighbours,
either way). Remaining points are rescored between rounds (clusters keep
their labels; m and k follow the shrinking cluster); stop when no point
qualifies. With a ratio or a count, every finite score is a candidate, on
the unit-free score m*dH, and rounds stop when the target is met (the last
round takes only the lowest candidates it needs). Its entry in the registry
is :data:`cloudsieve.core.rules.RULES`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["prune"]


def prune(rule, pts, lab, options, **kw) -> np.ndarray:
    """The keep mask (n,) bool after the rounds."""
    from .distinct import on_distinct

    return on_distinct(rounds, rule.name, pts, lab, options, **kw)


def rounds(rule, P, L, *, threshold, target, score, coverage, max_rounds, report, kw) -> np.ndarray:
    """The rounds of *rule* (a name of the registry) on the distinct points P in canonical order."""
    from ..rounds import prune_in_rounds

    return prune_in_rounds(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw)
