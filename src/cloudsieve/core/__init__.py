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
- :mod:`.rules` (:func:`prune`: threshold, target, and the rounds of :mod:`.rounds`:
  iterative, coverage; one round's choice in :mod:`.selection`, the rounds without
  context in :mod:`.incremental`, their threads in :mod:`.chunks`);
- :mod:`.kernels`: the compiled (numba) loops (:mod:`.kernels.rounds`,
  :mod:`.kernels.lists`, :mod:`.kernels.rescore` for the rounds);
- :mod:`.simplify`: :func:`simplify_points`, all of it.

Public functions validate their input once and run kernels that assume valid input.
"""

from ._validation import neighbour_count
from .duplicates import exact_copies, first_copies
from .entropy import Scores, entropy_scores, score_points
from .fcm import FuzzyCMeans
from .kmeans import KMeans
from .refine import METHODS, refine_labels
from .rules import PAPER_THRESHOLD, RULES, prune, threshold_for_count, unit_free_scores
from .simplify import simplify_points
from ..errors import ConvergenceWarning

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
