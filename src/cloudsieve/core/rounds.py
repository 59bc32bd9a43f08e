"""The rounds of the ``iterative`` and ``coverage`` rules (DESIGN.md stage 5).

One round's choice: :func:`.selection.round_selection`. Between rounds points are
rescored: without context incrementally (:mod:`.incremental`), with context in
full (here). Contracts: :mod:`.rules.iterative`, :mod:`.rules.coverage`.
Public: :func:`prune_in_rounds` (validated input).
"""

from __future__ import annotations

import logging

import numpy as np

from ._validation import neighbour_count
from .entropy import score_unchecked
from .incremental import rounds_incremental
from .kernels import lists as kl
from .kernels import rounds as kr
from .selection import RoundTest, round_selection

__all__ = ["prune_in_rounds"]

logger = logging.getLogger(__name__)


def _padded(indptr: np.ndarray, indices: np.ndarray, width: int | None = None) -> np.ndarray:
    """CSR neighbour lists as an (n, width) int64 array padded with -1."""
    n = len(indptr) - 1
    ln = np.diff(indptr)
    width = int(ln.max(initial=0)) if width is None else width
    out = np.full((n, width), -1, dtype=np.int64)
    rows = np.repeat(np.arange(n), ln)
    cols = np.arange(len(indices)) - np.repeat(indptr[:-1], ln)
    out[rows, cols] = indices
    return out


def _first_independent(cand: np.ndarray, nb: np.ndarray, n: int, kk: np.ndarray | None = None) -> np.ndarray:
    """Greedy independent set of ``cand`` (priority order) in the symmetric k-NN graph, in that order.

    ``nb`` (n, K) padded with -1 (or n); with ``kk`` row i holds kk[i] neighbours.
    Computed by :func:`.kernels.rounds.select_round`.
    """
    cand = np.asarray(cand, dtype=np.int64)
    nb = np.asarray(nb, dtype=np.int64)
    if len(cand) == 0:
        return cand
    kk = np.full(n, nb.shape[1], dtype=np.int64) if kk is None else np.asarray(kk, dtype=np.int64)
    return kr.select_round(cand, nb, kk, np.zeros(0, dtype=bool), -1)


def prune_in_rounds(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw):
    """The iterative/coverage rules: the keep mask (n,) bool of the canonically ordered points P.

    ``L`` (n,) int64 labels 0..c-1; ``target`` a kept count or None; ``report`` gets
    the count dropped each round; ``kw``: arguments of :func:`.entropy.score_unchecked`.
    Without context only touched clusters are rescored (:func:`.incremental.rounds_incremental`).
    """
    if kw["ctx"] is None:
        return rounds_incremental(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw)
    n = len(P)
    alive = np.ones(n, dtype=bool)
    n_alive = n
    use_unit = target is not None or score == "unit_free"
    K = int(neighbour_count(np.bincount(L).max(), kw["k0"], kw["k_min"]))
    val = np.full(n, np.inf)
    nb = np.full((n, K), -1, dtype=np.int64)

    def rescore(sub):
        s = score_unchecked(P[sub], L[sub], **kw)
        val[sub] = s.unit_free if use_unit else s.delta_h
        nb[sub] = -1
        nbs = s.neighbours
        if nbs.shape[1]:
            nb[sub, : nbs.shape[1]] = np.where(nbs >= 0, sub[np.maximum(nbs, 0)], -1)

    rescore(np.arange(n))
    rnd = 0
    test = RoundTest(rule, threshold, target, coverage)
    while max_rounds is None or rnd < max_rounds:
        sel = round_selection(P, alive, val, np.arange(n), nb, n_alive, test)
        if len(sel) == 0:
            break
        alive[sel] = False
        n_alive -= len(sel)
        val[sel] = np.inf
        nb[sel] = -1
        rnd += 1
        report(len(sel))
        logger.debug("round %d: dropped %d, %d left", rnd, len(sel), n_alive)
        sub = np.flatnonzero(alive)
        if len(sub):
            rescore(sub)
    return alive


def _covered(P, nb, cand, coverage, kk=None):
    """Which candidates may go without opening a gap wider than the local spacing.

    y qualifies when r_1(y) <= coverage * median of r_1 over its k nearest, so
    isolated points stay whatever their score. ``nb``, ``kk`` as
    :func:`_first_independent`. Returns bool (len(cand),) (:func:`.kernels.rounds.covered_mask`).
    """
    nb = np.asarray(nb, dtype=np.int64)
    kk = np.full(len(P), nb.shape[1], dtype=np.int64) if kk is None else np.asarray(kk, dtype=np.int64)
    P = np.ascontiguousarray(P, dtype=np.float64)
    return kr.covered_mask(nb, kk, kl.spacings(P, nb, kk), np.asarray(cand, dtype=np.int64), float(coverage))
