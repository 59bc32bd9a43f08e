"""The method in memory, on numpy arrays: no dask, no zarr.

One module per stage of the method: :mod:`.cluster` (K-means, fuzzy C-means),
:mod:`.entropy` (the k-NN density entropy scores), :mod:`.prune` (refinement,
the rules and :func:`simplify_points`).
"""

from .cluster import ConvergenceWarning, FuzzyCMeans, KMeans
from .entropy import Scores, entropy_scores, neighbour_count, score_points
from .prune import (
    METHODS,
    RULES,
    prune,
    refine_labels,
    simplify_points,
    threshold_for_count,
    unit_free_scores,
)

__all__ = [
    "KMeans",
    "FuzzyCMeans",
    "ConvergenceWarning",
    "Scores",
    "entropy_scores",
    "neighbour_count",
    "score_points",
    "METHODS",
    "RULES",
    "prune",
    "refine_labels",
    "simplify_points",
    "threshold_for_count",
    "unit_free_scores",
]
