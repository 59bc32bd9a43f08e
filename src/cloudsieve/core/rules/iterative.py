"""Rule iterative: the paper's test in rounds (:mod:`cloudsieve.core.rounds`).

Each round drops candidates (score <= S, lowest first) no two of which are k-NN
neighbours; the rest are rescored (labels kept, m and k follow). Stops when none
qualifies. With a ratio or count, every finite m*dH is a candidate and the rounds
stop at the target.
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
