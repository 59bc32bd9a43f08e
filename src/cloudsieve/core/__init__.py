"""The method in memory, on numpy arrays (no dask, no zarr); one module per stage.

- :mod:`._validation`: input checks and the k formula (:func:`neighbour_count`);
- :mod:`.knn`: point orders, grouping by cluster, k nearest inside clusters;
- :mod:`.duplicates`: exact copies (:func:`exact_copies`);
- :mod:`.cluster`, :mod:`.kmeans` (:class:`KMeans`), :mod:`.fcm` (:class:`FuzzyCMeans`),
  :mod:`.centres`: clustering and nearest-centre queries;
- :mod:`.refine`: :func:`refine_labels`;
- :mod:`.entropy`: :func:`score_points`, :func:`entropy_scores`, the leave-one-out ΔH;
- :mod:`.rules`: one module per rule and :func:`prune` (table: :mod:`cloudsieve.rule_table`);
  rounds in :mod:`.rounds`, :mod:`.selection`, :mod:`.incremental`, :mod:`.chunks`;
- :mod:`.kernels`: the compiled (numba) kernels;
- :mod:`.simplify`: :func:`simplify_points`.

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
