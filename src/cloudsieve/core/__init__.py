"""The method in memory, on numpy arrays (no dask, no zarr); one module per stage (docs/architecture.md,
"Modules").

Public functions validate input once and call kernels that assume it valid.
Names are imported at first use, so no module loads numba or scipy it does not need.
"""

from ..lazy import lazy_names

#: where each public name lives; imported at first use (PEP 562)
_LAZY = {
    "neighbour_count": "._validation", "exact_copies": ".duplicates", "first_copies": ".duplicates",
    "Scores": ".entropy", "entropy_scores": ".entropy", "score_points": ".entropy", "FuzzyCMeans": ".fcm",
    "KMeans": ".kmeans", "METHODS": ".refine", "refine_labels": ".refine", "PAPER_THRESHOLD": ".rules",
    "RULES": ".rules", "prune": ".rules", "threshold_for_count": ".rules", "unit_free_scores": ".rules",
    "simplify_points": ".simplify", "ConvergenceWarning": "..errors",
}

__getattr__, __dir__ = lazy_names(__name__, _LAZY)
__all__ = list(_LAZY)
