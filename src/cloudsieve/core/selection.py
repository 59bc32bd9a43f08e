"""One round of the ``iterative`` and ``coverage`` rules: which points it drops (DESIGN.md stage 5).

The candidates (score <= S, or every finite score with a target) are taken
lowest score first (ties: a unique id, the canonical index), in a greedy
independent set of the k-NN graph (no two points dropped in one round are
k-NN neighbours, either way); ``coverage`` first keeps only the candidates
whose nearest-neighbour distance is at most the median of their neighbours'
(:func:`.kernels.rounds.covered_rows`). With a target the round stops at it.
The kernels are in :mod:`.kernels.rounds`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .. import rule_table as registry
from .chunks import ClusterChunks
from .kernels import lists as kl
from .kernels import rounds as kr

__all__ = ["RoundTest", "round_selection"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RoundTest:
    """What a round of ``iterative``/``coverage`` tests: the *rule* (a name of the registry that runs rounds,
    :data:`cloudsieve.rule_table.RULES`), the *threshold* S, the kept count *target* (None: the threshold
    decides) and the *coverage* factor."""

    rule: str
    threshold: float
    target: int | None
    coverage: float


def round_selection(P, alive, val, tie, nb, n_alive, test: RoundTest, kk=None, r1=None,
                    chunked: ClusterChunks | None = None) -> np.ndarray:
    """The points one round of ``iterative``/``coverage`` drops (empty: the rounds stop).

    Candidates are the alive points with val <= threshold (with a target: any
    finite val), lowest val first, ties by ``tie``; ``coverage`` keeps those
    that pass the coverage test (on ``r1``, computed when not given); then a
    greedy independent set in the k-NN graph ``nb``, cut at the target (then
    in priority order, otherwise in any order).

    Parameters
    ----------
    P : ndarray of shape (n, p), float64
    alive : ndarray of shape (n,), bool
    val : ndarray of shape (n,), float64
        Scores (+inf: never a candidate).
    tie : ndarray of shape (n,), int64
        Unique ids breaking ties of val.
    nb : ndarray of shape (n, K), int32 or int64
        Neighbour lists, nearest first; entries outside [0, n) are none.
    n_alive : int
    test : RoundTest
    kk : ndarray of shape (n,), int64, optional
        Row i holds kk[i] neighbours (default: K).
    r1 : ndarray of shape (n,), float64, optional
        Distance of each row to its first neighbour, +inf where kk = 0.
    chunked : ClusterChunks, optional
        The points are grouped by cluster and every list stays inside its
        cluster: each cluster is run on its own, on the chunks' threads.

    Returns
    -------
    ndarray of shape (m,), int64
        The rows dropped (empty: the rounds stop).
    """
    rule, threshold, target, coverage = test.rule, test.threshold, test.target, test.coverage
    if target is not None and n_alive <= target:
        return np.zeros(0, dtype=np.int64)
    n = len(P)
    if kk is None:
        kk = np.full(n, nb.shape[1], dtype=np.int64)
    use_cov = registry.get(rule).coverage_test
    if use_cov and r1 is None:
        r1 = kl.spacings(P, nb, kk)
    limit = -1 if target is None else n_alive - target
    if chunked is not None:
        r1c = r1 if use_cov else np.zeros(0)
        sel = np.concatenate(chunked.map(lambda i, c0, c1, a, b: kr.select_clusters(
            chunked.starts, c0, c1, alive, val, float(threshold), target is not None, tie, nb, kk, r1c,
            float(coverage))))
        if 0 <= limit < len(sel):  # the first ``limit`` in priority order
            keys = val[sel]
            o = np.argsort(keys)
            sel = sel[o]
            kr.break_ties(sel, keys[o], tie)
            sel = sel[:limit]
    else:
        ok = np.zeros(0, dtype=bool)
        if use_cov:
            ok = np.zeros(n, dtype=bool)
            kr.covered_rows(nb, kk, r1, float(coverage), 0, n, ok)
        pool, keys = kr.candidates(alive, val, float(threshold), target is not None)
        o = np.argsort(keys)
        cand = pool[o]
        kr.break_ties(cand, keys[o], tie)
        sel = kr.select_round(cand, nb, kk, ok, limit)
    if len(sel) == 0 and target is not None:
        logger.warning("rule %s stopped at %d points, target %d: no point qualifies", rule, n_alive, target)
    return sel
