"""Rule coverage (cloudsieve's, not the paper's): ``iterative`` where a point may go only where it is covered.

A candidate y also needs r_1(y) <= coverage * median of r_1 over its k nearest
(r_1: distance to the nearest remaining point), so no gap wider than the local
spacing opens and isolated points, which |dH| ranks most redundant, stay (errors:
benchmarks/quality.py). The test is the registry's ``coverage_test``
(:data:`cloudsieve.core.rules.RULES`), read by :func:`cloudsieve.core.selection.round_selection`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["prune"]


def prune(rule, pts, lab, options, **kw) -> np.ndarray:
    """The keep mask (n,) bool after the rounds with the coverage test."""
    from .distinct import on_distinct
    from .iterative import rounds

    return on_distinct(rounds, rule.name, pts, lab, options, **kw)
