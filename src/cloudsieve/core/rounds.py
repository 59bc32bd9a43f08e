"""The rounds of the ``iterative`` and ``coverage`` rules (DESIGN.md stage 5).

In each round the candidates (score <= S, or every finite score with a
target) are taken lowest score first, in a greedy independent set of the
k-NN graph (no two points dropped in one round are k-NN neighbours, either
way); ``coverage`` first keeps only the candidates whose nearest-neighbour
distance is at most the median of their neighbours' (:func:`_covered`). The
remaining points are rescored between rounds: incrementally without context
(only the clusters that lost a point, from the kept k-NN lists), by a full
rescoring with context. See :mod:`.rules` for the rules' contracts.

Public: :func:`prune_in_rounds`, on validated input (called by
:func:`.rules.prune_unchecked`).
"""

from __future__ import annotations

import logging
import os

import numpy as np

from ._validation import neighbour_count
from .entropy import entropy_change, score_unchecked
from .kernels import rounds as kr
from .knn import group, knn_clusters, knn_query, mark_duplicates

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
    """Greedy independent set of ``cand`` (priority order) in the symmetric k-NN graph.

    ``nb`` (n, K) holds each point's neighbours, padded with -1 (or n). Returns
    the selected candidates in priority order (with ``kk``, row i holds k =
    kk[i] neighbours, the columns after them are ignored): exactly what a
    sequential pass keeps (take a candidate unless one of its neighbours, or a
    point having it as a neighbour, was taken before), computed by that pass
    (:func:`.kernels.rounds.select_round`).
    """
    cand = np.asarray(cand, dtype=np.int64)
    nb = np.asarray(nb, dtype=np.int64)
    if len(cand) == 0:
        return cand
    kk = np.full(n, nb.shape[1], dtype=np.int64) if kk is None else np.asarray(kk, dtype=np.int64)
    return kr.select_round(cand, nb, kk, np.zeros(0, dtype=bool), -1)


def prune_in_rounds(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw):
    """The iterative/coverage rules: the keep mask (n,) bool of the canonically ordered points P.

    ``L`` (n,) int64 labels 0..c-1; ``target`` a kept count or None; ``report``
    called with the count dropped in each round; ``kw`` the scoring arguments
    of :func:`.entropy.score_unchecked` (k0, k_min, dim, ctx, threads). With
    context every remaining point is rescored between rounds; without, only
    the touched clusters (:func:`_rounds_local`).
    """
    if kw["ctx"] is None:
        return _rounds_local(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw)
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
    while max_rounds is None or rnd < max_rounds:
        sel = _round_selection(P, alive, val, np.arange(n), nb, n_alive, rule, threshold, target, coverage)
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


def _round_selection(P, alive, val, tie, nb, n_alive, rule, threshold, target, coverage, kk=None,
                     r1=None, starts=None) -> np.ndarray:
    """The points one round of ``iterative``/``coverage`` drops (empty: the rounds stop).

    Candidates are the alive points with val <= threshold (with a target: any
    finite val), lowest val first, ties by ``tie`` (unique ids); ``coverage``
    keeps those that pass :func:`_covered` (on ``r1``, the r_1 of every point,
    computed when not given); then a greedy independent set in the k-NN graph
    ``nb`` (rows cut at ``kk``), cut at the target (then in priority order,
    otherwise in any order). ``starts`` (c + 1,): the points are grouped by
    cluster and no list leaves its cluster, so each cluster is run on its own.
    """
    if target is not None and n_alive <= target:
        return np.zeros(0, dtype=np.int64)
    if kk is None:
        kk = np.full(len(P), nb.shape[1], dtype=np.int64)
    if rule != "coverage":
        ok = np.zeros(0, dtype=bool)
    else:
        ok = kr.covered_rows(nb, kk, kr.spacings(P, nb, kk) if r1 is None else r1, float(coverage))
    limit = -1 if target is None else n_alive - target
    if starts is not None:
        sel = kr.select_clusters(starts, alive, val, float(threshold), target is not None, tie, nb, kk, ok)
        if 0 <= limit < len(sel):  # the first ``limit`` in priority order
            keys = val[sel]
            o = np.argsort(keys)
            sel = sel[o]
            kr.break_ties(sel, keys[o], tie)
            sel = sel[:limit]
    else:
        pool, keys = kr.candidates(alive, val, float(threshold), target is not None)
        o = np.argsort(keys)
        cand = pool[o]
        kr.break_ties(cand, keys[o], tie)
        sel = kr.select_round(cand, nb, kk, ok, limit)
    if len(sel) == 0 and target is not None:
        logger.warning("rule %s stopped at %d points, target %d: no point qualifies", rule, n_alive, target)
    return sel


# Spare neighbours kept per point by the rounds: a point needs a new k-NN query only
# after losing more than this many of its k + 1 + _SPARE nearest (or k + 1 - k' when k falls).
_SPARE = 4


def _rounds_local(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw):
    """The iterative/coverage rules without context: incremental rescoring.

    Without context a cluster's scores depend on its own points only, so after
    a round only the clusters that lost a point change. Every point keeps its
    k + 1 + e nearest (e <= _SPARE spares), nearest first; a dropped point
    leaves the lists, and as long as a list keeps k' + 1 points (k' the
    cluster's new k) they are still the k' + 1 nearest among the remaining
    points (removing points brings none closer): r_k' and r_(k'+1) are then
    the distances to its k'-th and (k'+1)-th entries, computed as the k-d
    tree does. Only shorter lists need a new k-d tree query. Then W, A and
    every score of a touched cluster are recomputed in O(m k). A cluster with
    exact copies is scored again whole. The scores are those of a full
    rescoring (the same formulas on the same distances; sums may differ in
    the last bit from :func:`.entropy.score_points`, which orders the points of a
    cluster differently).

    All the state is kept in the grouped order of :func:`.knn.group`
    (ties between candidates are still broken by canonical index).
    """
    k0, k_min, dim = kw["k0"], kw["k_min"], kw["dim"]
    threads = int(kw["threads"] or os.cpu_count() or 1)
    n = len(P)
    inv, order, sizes = group(P, L)
    g = P[order]
    ginv = inv[order]
    c = len(sizes)
    groups, dup = knn_clusters(g, ginv, sizes, k0, k_min, threads, extra=_SPARE)
    K = max((grp[0] for grp in groups), default=0)
    kk = np.zeros(n, dtype=np.int64)  # k of a scored point, 0 otherwise
    rk = np.ones(n)
    rk1 = np.ones(n)
    idt = np.int32 if n < 2**31 - 1 else np.int64  # half the memory traffic of the rounds' kernels
    nbx = np.full((n, K + 1 + _SPARE), n, dtype=idt)  # nearest first (grouped positions), n after
    kcl = np.zeros(c, dtype=np.int64)  # k of a scored cluster, 0 otherwise
    alive = np.ones(n, dtype=bool)
    val = np.full(n, np.inf)
    val[dup] = 0.0

    r1 = np.full(n, np.inf)  # r_1 of the rows with a list (kk > 0), +inf for the others

    def store(grps):
        for k, r, a, b, x in grps:
            kr.store_lists(r, k, a, b, x, g, kk, rk, rk1, r1, nbx)

    def query(whole):
        """Find the copies in the whole clusters again, then m, k; the rows to query."""
        wrows = np.flatnonzero(alive & whole[ginv])
        if len(wrows) == 0:
            return wrows
        kk[wrows] = 0
        r1[wrows] = np.inf
        nbx[wrows] = n
        val[wrows] = np.inf
        distinct = mark_duplicates(g, ginv, wrows, dup)
        val[wrows[dup[wrows]]] = 0.0
        m = np.bincount(ginv[distinct], minlength=c)
        k2 = neighbour_count(m, k0, k_min)
        ok = whole & (m >= k2 + 2)
        kcl[whole] = np.where(ok, k2, 0)[whole]
        return distinct[ok[ginv[distinct]]]

    def run(q):
        """New k-NN lists for the rows q (ascending): by brute force inside the cluster
        (:func:`.kernels.rounds.refresh_lists`), by the k-d tree for rows whose list has
        tied distances (so their tie order is the tree's, as with a query of all of q)."""
        if len(q) == 0:
            return
        lists, kq, a, b, d1, status = kr.refresh_lists(g, ginv, starts, alive, dup, q, kcl, _SPARE, nbx.shape[1])
        if (status == 2).any():
            tree_q = q  # a zero distance: the tree's cluster flag decides, query them all
        else:
            kr.store_refreshed(q, status, lists, kq, a, b, d1, kk, rk, rk1, r1, nbx)
            tree_q = q[status == 1]
        if len(tree_q):
            need = np.zeros(c, dtype=bool)
            need[ginv[q]] = True  # the tree of all of q's clusters, as a query of all of q would build
            trows = np.flatnonzero(alive & ~dup & need[ginv])
            store(knn_query(g, ginv, trows, kcl, threads, query=np.searchsorted(trows, tree_q), extra=_SPARE)[0])
        logger.debug("k-NN lists refreshed for %d points, %d by the k-d tree", len(q), len(tree_q))

    starts = np.zeros(c + 1, dtype=np.int64)  # cluster j: rows starts[j] to starts[j + 1]
    np.cumsum(sizes, out=starts[1:])
    store(groups)
    for k, r, _, _, _ in groups:
        kcl[ginv[r]] = k
    del groups
    n_alive = n
    use_unit = target is not None or score == "unit_free"
    acc_w = np.zeros(n)  # scratch of kr.entropy_deltas
    acc_g = np.zeros(n)

    def rescore(touched):
        """Scores of the scored points of the touched clusters, from the kept k-NN data."""
        rows = kr.scored_rows(touched, ginv, kk)  # kk > 0: alive, distinct, in a scored cluster
        if len(rows) == 0:
            return
        # the terms of .entropy.entropy_terms, with numpy's log and exp
        lw, lw1 = kr.log_weights(rows, ginv, c, np.log(rk[rows]), np.log(rk1[rows]), -float(dim))
        dW, dG, Wc = kr.entropy_deltas(rows, ginv, c, kk, nbx, np.exp(lw), np.exp(lw1), lw, lw1, acc_w, acc_g)
        dh = np.abs(entropy_change(dW, dG, Wc))
        m = kr.cluster_counts(ginv, alive, dup, c)[0] if use_unit else kcl
        kr.store_scores(rows, ginv, dh, m, use_unit, val)

    rescore(np.ones(c, dtype=bool))
    rnd = 0
    while max_rounds is None or rnd < max_rounds:
        # ties: canonical index (the input order, not the grouped one)
        sel = _round_selection(g, alive, val, order, nbx, n_alive, rule, threshold, target, coverage, kk, r1,
                               starts)
        if len(sel) == 0:
            break
        touched = np.zeros(c, dtype=bool)
        kr.drop_rows(sel, alive, val, kk, r1, nbx, ginv, touched)
        n_alive -= len(sel)
        rnd += 1
        report(len(sel))

        m, copies = kr.cluster_counts(ginv, alive, dup, c)
        k_new = neighbour_count(m, k0, k_min)
        whole = touched & ((copies > 0) | (m < k_new + 2))
        part = touched & ~whole
        # part: drop the removed points from the lists; a list still holding k' + 1 points gives r_k'
        q_part = kr.repack_lists(g, ginv, kk, rk, rk1, r1, nbx, part, k_new, sel)
        kcl[part] = k_new[part]
        q_whole = query(whole)
        logger.debug("round %d: dropped %d, %d left; %d clusters touched (%d whole), k-NN query for %d + %d points",
                     rnd, len(sel), n_alive, touched.sum(), whole.sum(), len(q_part), len(q_whole))
        run(np.union1d(q_part, q_whole) if len(q_whole) else q_part)
        rescore(touched)
    out = np.empty(n, dtype=bool)
    out[order] = alive
    return out


def _covered(P, nb, cand, coverage, kk=None):
    """Which candidates may go without opening a gap wider than the local spacing.

    r_1(y) is y's nearest-neighbour distance. A candidate y qualifies when
    r_1(y) <= coverage * median of r_1 over y's k nearest: y sits where points
    are at least as dense as around it. An isolated point (outlier, edge of a
    thin part), whose nearest neighbour is far compared with its neighbours'
    spacing, stays, whatever its entropy score. ``nb`` (n, K) padded with -1
    (or n); with ``kk`` (n,), row i holds kk[i] neighbours. Returns a bool
    mask (len(cand),) (:func:`.kernels.rounds.covered_mask`).
    """
    nb = np.asarray(nb, dtype=np.int64)
    kk = np.full(len(P), nb.shape[1], dtype=np.int64) if kk is None else np.asarray(kk, dtype=np.int64)
    return kr.covered_mask(np.ascontiguousarray(P, dtype=np.float64), nb, kk,
                           np.asarray(cand, dtype=np.int64), float(coverage))
