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
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._validation import neighbour_count
from .entropy import entropy_change, score_unchecked
from .kernels import lists as kl
from .kernels import rescore as ks
from .kernels import rounds as kr
from .knn import group, knn_query, mark_duplicates

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
                     r1=None, chunked=None) -> np.ndarray:
    """The points one round of ``iterative``/``coverage`` drops (empty: the rounds stop).

    Candidates are the alive points with val <= threshold (with a target: any
    finite val), lowest val first, ties by ``tie`` (unique ids); ``coverage``
    keeps those that pass :func:`_covered` (on ``r1``, the r_1 of every point,
    computed when not given); then a greedy independent set in the k-NN graph
    ``nb`` (rows cut at ``kk``), cut at the target (then in priority order,
    otherwise in any order). ``chunked``: a :class:`_Chunks` of the points,
    grouped by cluster with every list inside its cluster, so that each
    cluster is run on its own.
    """
    if target is not None and n_alive <= target:
        return np.zeros(0, dtype=np.int64)
    n = len(P)
    if kk is None:
        kk = np.full(n, nb.shape[1], dtype=np.int64)
    use_cov = rule == "coverage"
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


class _Chunks:
    """Cluster ranges of points grouped by cluster (cluster j: rows starts[j] to starts[j + 1]),
    of about equal point counts: one for one thread, four per thread otherwise; :meth:`map`
    runs a function of (range number, c0, c1, first row, end row) on each, on the threads,
    results in range order. A cluster's result never depends on the ranges, so no result
    depends on ``threads``."""

    def __init__(self, starts: np.ndarray, threads: int, pool: ThreadPoolExecutor | None):
        self.starts = starts
        c = len(starts) - 1
        parts = 1 if pool is None else min(c, 4 * threads)
        cuts = np.searchsorted(starts, np.linspace(0, starts[-1], parts + 1)[1:-1])
        bounds = np.unique(np.r_[0, cuts[(cuts > 0) & (cuts < c)], c])
        self.ranges = [(i, int(c0), int(c1), int(starts[c0]), int(starts[c1]))
                       for i, (c0, c1) in enumerate(zip(bounds[:-1], bounds[1:]))]
        self.pool = pool if len(self.ranges) > 1 else None

    def map(self, fn):
        if self.pool is None:
            return [fn(*r) for r in self.ranges]
        return list(self.pool.map(lambda r: fn(*r), self.ranges))


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
    tree does. Only shorter lists are made again (:func:`.kernels.lists.refresh_lists`,
    or the k-d tree when distances tie). Then W, A and every score of a
    touched cluster are recomputed in O(m k). A cluster with exact copies is
    scored again whole. The scores are those of a full rescoring (the same
    formulas on the same distances; sums may differ in the last bit from
    :func:`.entropy.score_points`, which orders the points of a cluster
    differently).

    All the state is kept in the grouped order of :func:`.knn.group` (ties
    between candidates are still broken by canonical index); the kernels run
    on ranges of clusters, on ``threads`` threads (:class:`_Chunks`).
    """
    threads = int(kw["threads"] or os.cpu_count() or 1)
    if threads <= 1:
        return _Local(P, L, kw, threads, None).run(rule, threshold, target, score, coverage, max_rounds, report)
    with ThreadPoolExecutor(threads) as pool:
        return _Local(P, L, kw, threads, pool).run(rule, threshold, target, score, coverage, max_rounds, report)


class _Local:
    """The state of :func:`_rounds_local` (rows: the points in grouped order)."""

    def __init__(self, P, L, kw, threads, pool):
        self.k0, self.k_min, self.dim = kw["k0"], kw["k_min"], kw["dim"]
        self.threads = threads
        n = self.n = len(P)
        inv, self.order, sizes = group(P, L)
        self.g = P[self.order]
        self.ginv = inv[self.order]
        c = self.c = len(sizes)
        starts = np.zeros(c + 1, dtype=np.int64)  # cluster j: rows starts[j] to starts[j + 1]
        np.cumsum(sizes, out=starts[1:])
        self.chunks = _Chunks(starts, threads, pool)
        self.dup = np.zeros(n, dtype=bool)
        self.kk = np.zeros(n, dtype=np.int64)  # k of a scored point, 0 otherwise
        self.rk = np.ones(n)
        self.rk1 = np.ones(n)
        self.r1 = np.full(n, np.inf)  # r_1 of the rows with a list (kk > 0), +inf for the others
        K = int(neighbour_count(sizes.max(initial=0), self.k0, self.k_min))
        idt = np.int32 if n < 2**31 - 1 else np.int64  # half the memory traffic of the kernels
        self.nbx = np.full((n, K + 1 + _SPARE), n, dtype=idt)  # nearest first (grouped positions), n after
        self.kcl = np.zeros(c, dtype=np.int64)  # k of a scored cluster, 0 otherwise
        self.alive = np.ones(n, dtype=bool)
        self.first_lists(sizes)
        self.val = np.full(n, np.inf)
        self.val[self.dup] = 0.0
        self.acc_w = np.zeros(n)  # scratch of kernels.rescore.entropy_deltas
        self.acc_g = np.zeros(n)

    def first_lists(self, sizes):
        """The lists of every point, as :func:`.knn.knn_clusters` (``extra=_SPARE``) gives them:
        its copies marked in ``dup``, the lists by :meth:`lists`, the k-d tree queries of
        knn_clusters asked only for rows with tied distances (or all of them when a zero
        distance appears where knn_clusters would not expect one)."""
        g, ginv, dup, c = self.g, self.ginv, self.dup, self.c
        kc = neighbour_count(sizes, self.k0, self.k_min)
        ok = sizes >= kc + 2
        okr = ok[ginv]
        small = np.flatnonzero(~okr & (sizes[ginv] > 1))
        if len(small):  # never scored, but their copies still score 0
            mark_duplicates(g, ginv, small, dup)
        rows = np.flatnonzero(okr)
        if len(rows) == 0:
            return
        # knn_clusters' first tree: all the rows of the clusters large enough, copies included
        res, status = self.lists(rows, okr, np.zeros(self.n, dtype=bool), np.where(ok, kc, 0))
        flagged = np.zeros(c, dtype=bool)  # clusters with copies (a zero distance), done again below
        flagged[ginv[rows[status == 2]]] = True
        self.store_lists(rows, res, ~flagged[ginv[rows]])
        tied = rows[(status == 1) & ~flagged[ginv[rows]]]
        if len(tied):
            self.store(knn_query(g, ginv, rows, kc, self.threads, query=np.searchsorted(rows, tied), extra=_SPARE)[0])
        if flagged.any():  # the distinct points of these clusters (m and k follow)
            distinct = mark_duplicates(g, ginv, np.flatnonzero(flagged[ginv]), dup)
            m2 = np.bincount(ginv[distinct], minlength=c)
            k2 = neighbour_count(m2, self.k0, self.k_min)
            rows2 = distinct[(m2 >= k2 + 2)[ginv[distinct]]]
            if len(rows2):
                member = np.zeros(self.n, dtype=bool)
                member[rows2] = True
                res, status = self.lists(rows2, member, np.zeros(self.n, dtype=bool), np.where(m2 >= k2 + 2, k2, 0))
                if (status == 2).any():
                    self.store(knn_query(g, ginv, rows2, k2, self.threads, extra=_SPARE)[0])
                else:
                    self.store_lists(rows2, res, np.ones(len(rows2), dtype=bool))
                    tied = rows2[status == 1]
                    if len(tied):
                        self.store(knn_query(g, ginv, rows2, k2, self.threads, query=np.searchsorted(rows2, tied),
                                             extra=_SPARE)[0])
        has = self.kk > 0
        self.kcl[ginv[has]] = self.kk[has]
        logger.debug("first k-NN lists for %d points (%d asked of the k-d tree); %d clusters with copies",
                     int(has.sum()), len(tied), int(flagged.sum()))

    def lists(self, q, member, dup, kcl):
        """The lists of the rows q (ascending) among the ``member`` rows of their cluster that are not
        ``dup``, k = kcl of the cluster (:func:`.kernels.lists.refresh_lists`, on the threads):
        (the results of each range, with the range's q), status (len(q),) int8."""
        cut = np.searchsorted(q, [r[3] for r in self.chunks.ranges] + [self.n])  # q of each range
        res = self.chunks.map(lambda i, c0, c1, a, b: (q[cut[i] : cut[i + 1]],) + kl.refresh_lists(
            self.g, self.ginv, self.chunks.starts, member, dup, q[cut[i] : cut[i + 1]], kcl, _SPARE,
            self.nbx.shape[1]))
        return res, np.concatenate([r[6] for r in res])

    def store_lists(self, q, res, keep):
        """Write the lists of :meth:`lists` with status 0 and ``keep`` (len(q),) into the state."""
        off = 0
        for qs, ls, kq, a, b, d1, st in res:
            st = np.where(keep[off : off + len(qs)], st, 1)
            off += len(qs)
            kl.store_refreshed(qs, st, ls, kq, a, b, d1, self.kk, self.rk, self.rk1, self.r1, self.nbx)

    def store(self, grps):
        """Write the k-NN results of :func:`.knn.knn_query` into the state."""
        for k, r, a, b, x in grps:
            kl.store_lists(r, k, a, b, x, self.g, self.kk, self.rk, self.rk1, self.r1, self.nbx)

    def run(self, rule, threshold, target, score, coverage, max_rounds, report):
        """The rounds: the keep mask (n,) bool in the order of the points given."""
        n, c, ginv, alive = self.n, self.c, self.ginv, self.alive
        use_unit = target is not None or score == "unit_free"
        self.rescore(np.ones(c, dtype=bool), use_unit)
        n_alive = n
        rnd = 0
        while max_rounds is None or rnd < max_rounds:
            # ties: canonical index (the input order, not the grouped one)
            sel = _round_selection(self.g, alive, self.val, self.order, self.nbx, n_alive, rule, threshold, target,
                                   coverage, self.kk, self.r1, self.chunks)
            if len(sel) == 0:
                break
            touched = np.zeros(c, dtype=bool)
            kr.drop_rows(sel, alive, self.val, self.kk, self.r1, self.nbx, ginv, touched)
            n_alive -= len(sel)
            rnd += 1
            report(len(sel))

            m, copies = kr.cluster_counts(ginv, alive, self.dup, c)
            k_new = neighbour_count(m, self.k0, self.k_min)
            whole = touched & ((copies > 0) | (m < k_new + 2))
            part = touched & ~whole
            # part: drop the removed points from the lists; a list still holding k' + 1 points gives r_k'
            removed = np.zeros(n + 1, dtype=bool)  # slot n: the padding
            removed[sel] = True
            q_part = np.concatenate(self.chunks.map(lambda i, c0, c1, a, b: kl.repack_lists(
                self.g, ginv, self.kk, self.rk, self.rk1, self.r1, self.nbx, part, k_new, removed, a, b)))
            self.kcl[part] = k_new[part]
            q_whole = self.query(whole)
            logger.debug("round %d: dropped %d, %d left; %d clusters touched (%d whole), new k-NN lists for "
                         "%d + %d points", rnd, len(sel), n_alive, touched.sum(), whole.sum(), len(q_part),
                         len(q_whole))
            self.refresh(np.union1d(q_part, q_whole) if len(q_whole) else q_part)
            self.rescore(touched, use_unit)
        out = np.empty(n, dtype=bool)
        out[self.order] = alive
        return out

    def query(self, whole):
        """Find the copies in the whole clusters again, then m, k; the rows needing new lists."""
        alive, ginv, dup = self.alive, self.ginv, self.dup
        wrows = np.flatnonzero(alive & whole[ginv])
        if len(wrows) == 0:
            return wrows
        self.kk[wrows] = 0
        self.r1[wrows] = np.inf
        self.nbx[wrows] = self.n
        self.val[wrows] = np.inf
        distinct = mark_duplicates(self.g, ginv, wrows, dup)
        self.val[wrows[dup[wrows]]] = 0.0
        m = np.bincount(ginv[distinct], minlength=self.c)
        k2 = neighbour_count(m, self.k0, self.k_min)
        ok = whole & (m >= k2 + 2)
        self.kcl[whole] = np.where(ok, k2, 0)[whole]
        return distinct[ok[ginv[distinct]]]

    def refresh(self, q):
        """New k-NN lists for the rows q (ascending) among the remaining points: by :meth:`lists`,
        by the k-d tree for rows whose list has tied distances (the tree of a query of all of q,
        so their tie order is the tree's)."""
        if len(q) == 0:
            return
        ginv = self.ginv
        res, status = self.lists(q, self.alive, self.dup, self.kcl)
        if (status == 2).any():
            tree_q = q  # a zero distance: the tree's cluster flag decides, query them all
        else:
            self.store_lists(q, res, np.ones(len(q), dtype=bool))
            tree_q = q[status == 1]
        if len(tree_q):
            need = np.zeros(self.c, dtype=bool)
            need[ginv[q]] = True  # the tree of all of q's clusters, as a query of all of q would build
            trows = np.flatnonzero(self.alive & ~self.dup & need[ginv])
            self.store(knn_query(self.g, ginv, trows, self.kcl, self.threads, query=np.searchsorted(trows, tree_q),
                                 extra=_SPARE)[0])
        logger.debug("new k-NN lists for %d points, %d by the k-d tree", len(q), len(tree_q))

    def rescore(self, touched, use_unit):
        """Scores of the scored points of the touched clusters, from the kept k-NN data."""
        ginv, kk = self.ginv, self.kk
        m = kr.cluster_counts(ginv, self.alive, self.dup, self.c)[0] if use_unit else self.kcl
        neg_dim = -float(self.dim)

        def part(i, c0, c1, a, b):
            rows = ks.scored_rows(touched, ginv, kk, a, b)  # kk > 0: alive, distinct, in a scored cluster
            if len(rows) == 0:
                return
            # the terms of .entropy.entropy_terms, with numpy's log and exp
            lw, lw1 = ks.log_weights(rows, ginv, c0, c1, np.log(self.rk[rows]), np.log(self.rk1[rows]), neg_dim)
            dW, dG, Wc = ks.entropy_deltas(rows, ginv, c0, c1, kk, self.nbx, np.exp(lw), np.exp(lw1), lw, lw1,
                                           self.acc_w, self.acc_g)
            ks.store_scores(rows, ginv, np.abs(entropy_change(dW, dG, Wc)), m, use_unit, self.val)

        self.chunks.map(part)


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
    P = np.ascontiguousarray(P, dtype=np.float64)
    return kr.covered_mask(nb, kk, kl.spacings(P, nb, kk), np.asarray(cand, dtype=np.int64), float(coverage))
