"""One round of the ``iterative`` and ``coverage`` rules: which points it drops (DESIGN.md stage 5).

Candidates (score <= S, or any finite score with a target) go lowest score first
(ties: canonical index) in a greedy independent set of the k-NN graph; ``coverage``
first keeps those passing :func:`.kernels.rounds.covered_rows`. With a target the
round stops at it.
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
    """What a round tests: *rule* (of :data:`cloudsieve.rule_table.RULES`), *threshold* S, kept count *target* (None: threshold), *coverage*."""

    rule: str
    threshold: float
    target: int | None
    coverage: float


def round_selection(P, alive, val, tie, nb, n_alive, test: RoundTest, kk=None, r1=None,
                    chunked: ClusterChunks | None = None) -> np.ndarray:
    """The rows one round of ``iterative``/``coverage`` drops, int64 (empty: the rounds stop).

    ``val`` (n,) scores (+inf: never a candidate), ``tie`` (n,) unique ids breaking its
    ties, ``nb`` (n, K) lists nearest first (entries outside [0, n) are none), row i
    holding ``kk[i]`` (default K); ``r1`` (n,) distance to the first neighbour (+inf
    where kk = 0; computed when not given). With ``chunked`` (lists inside clusters),
    each cluster runs on its own on the chunks' threads. Cut at the target in priority order.
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
