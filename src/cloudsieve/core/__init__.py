"""The method in memory, on numpy arrays: no dask, no zarr.

One module per stage, found by its name:

- :mod:`._validation`: the input checks and the one k formula (:func:`neighbour_count`);
- :mod:`.knn`: point orders, grouping by cluster, the k nearest inside clusters;
- :mod:`.duplicates`: exact copies (:func:`exact_copies`), the one policy of every rule;
- :mod:`.cluster` (the shared base and seeding), :mod:`.kmeans` (:class:`KMeans`),
  :mod:`.fcm` (:class:`FuzzyCMeans`), :mod:`.centres` (their nearest-centre queries and threads);
- :mod:`.kernels`: the compiled (numba) kernels the stages call;
- :mod:`.refine`: :func:`refine_labels`, KM or FCM into small clusters;
- :mod:`.entropy`: :func:`score_points`, :func:`entropy_scores`, the leave-one-out ΔH;
- :mod:`.rules`: one module per rule (their table, :data:`.rules.RULES`, is
  :mod:`cloudsieve.rule_table`) and :func:`prune`; the rounds of iterative and coverage in :mod:`.rounds` (one round's
  choice in :mod:`.selection`, the rounds without context in :mod:`.incremental`,
  their threads in :mod:`.chunks`);
- :mod:`.kernels`: the compiled (numba) loops (:mod:`.kernels.rounds`,
  :mod:`.kernels.lists`, :mod:`.kernels.rescore` for the rounds);
- :mod:`.simplify`: :func:`simplify_points`, all of it.

Public functions validate their input once (options: :mod:`cloudsieve.params`; arrays:
:mod:`._validation`) and run kernels that assume valid input. Each name is imported at its first
use, so importing a module of the package loads no numba or scipy it does not need.
"""

from importlib import import_module

#: where each public name lives; imported at its first use (PEP 562), so that a module of the package
#: (:mod:`.rules` among them) imports without numba or scipy
_LAZY = {
    "neighbour_count": "._validation", "exact_copies": ".duplicates", "first_copies": ".duplicates",
    "Scores": ".entropy", "entropy_scores": ".entropy", "score_points": ".entropy", "FuzzyCMeans": ".fcm",
    "KMeans": ".kmeans", "METHODS": ".refine", "refine_labels": ".refine", "PAPER_THRESHOLD": ".rules",
    "RULES": ".rules", "prune": ".rules", "threshold_for_count": ".rules", "unit_free_scores": ".rules",
    "simplify_points": ".simplify", "ConvergenceWarning": "..errors",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = [
    "KMeans",
    "FuzzyCMeans",
    "ConvergenceWarning",
    "Scores",
    "entropy_scores",
    "exact_copies",
    "first_copies",
    "neighbour_count",
    "score_points",
    "METHODS",
    "RULES",
    "PAPER_THRESHOLD",
    "prune",
    "refine_labels",
    "simplify_points",
    "threshold_for_count",
    "unit_free_scores",
]
