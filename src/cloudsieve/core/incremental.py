"""The ``iterative`` and ``coverage`` rounds without context: incremental rescoring (DESIGN.md stage 5).

Without context a cluster's scores depend on its own points only, so after a round
only touched clusters are rescored (:mod:`.kernels.rescore`) from k-NN lists kept
between rounds (:mod:`.kernels.lists`). Called by :func:`.rounds.prune_in_rounds`.
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._validation import neighbour_count
from .chunks import ClusterChunks
from .entropy import entropy_change
from .kernels import lists as kl
from .kernels import rescore as ks
from .kernels import rounds as kr
from .knn import group, knn_query, mark_duplicates, scorable_rows
from .selection import RoundTest, round_selection

__all__ = ["rounds_incremental", "SPARE"]

logger = logging.getLogger(__name__)

# Spare neighbours per point: a new k-NN query only after losing more than this many of the k + 1 + SPARE
SPARE = 4


def rounds_incremental(P, L, rule, threshold, target, score, coverage, max_rounds, report, kw):
    """The iterative/coverage rules without context: incremental rescoring.

    Each point keeps its k + 1 + e nearest (e <= SPARE). Removing points brings none
    closer, so while a list keeps k' + 1 entries (k' the cluster's new k) they give
    r_k' and r_(k'+1); only shorter lists are remade by
    :func:`.kernels.lists.refresh_lists`, rows with tied distances by the k-d tree of
    :func:`.knn.knn_query` (same tie order). Touched clusters are rescored in O(m k);
    clusters with copies whole. Scores equal a full rescoring's up to the last bit.
    State is in :func:`.knn.group` order; kernels run on :class:`.chunks.ClusterChunks`.
    """
    threads = int(kw["threads"] or os.cpu_count() or 1)
    if threads <= 1:
        return _Local(P, L, kw, threads, None).run(rule, threshold, target, score, coverage, max_rounds, report)
    with ThreadPoolExecutor(threads) as pool:
        return _Local(P, L, kw, threads, pool).run(rule, threshold, target, score, coverage, max_rounds, report)


class _Local:
    """The state of :func:`rounds_incremental` (rows: the points in grouped order)."""

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
        self.chunks = ClusterChunks(starts, threads, pool)
        self.dup = np.zeros(n, dtype=bool)
        self.kk = np.zeros(n, dtype=np.int64)  # k of a scored point, 0 otherwise
        self.rk = np.ones(n)
        self.rk1 = np.ones(n)
        self.r1 = np.full(n, np.inf)  # r_1 of the rows with a list (kk > 0), +inf for the others
        K = int(neighbour_count(sizes.max(initial=0), self.k0, self.k_min))
        idt = np.int32 if n < 2**31 - 1 else np.int64  # half the memory traffic of the kernels
        self.nbx = np.full((n, K + 1 + SPARE), n, dtype=idt)  # nearest first (grouped positions), n after
        self.kcl = np.zeros(c, dtype=np.int64)  # k of a scored cluster, 0 otherwise
        self.alive = np.ones(n, dtype=bool)
        self.first_lists(sizes)
        self.val = np.full(n, np.inf)
        self.val[self.dup] = 0.0
        self.acc_w = np.zeros(n)  # scratch of kernels.rescore.entropy_deltas
        self.acc_g = np.zeros(n)

    def first_lists(self, sizes):
        """The lists of every point as :func:`.knn.knn_clusters` (``extra=SPARE``) gives them.

        Same copies in ``dup``; lists by :meth:`lists`; k-d tree queries only for rows with tied distances.
        """
        g, ginv, dup, c = self.g, self.ginv, self.dup, self.c
        kc, ok, okr, rows = scorable_rows(g, ginv, sizes, self.k0, self.k_min, dup)
        if len(rows) == 0:
            return
        # knn_clusters' first tree: all the rows of the clusters large enough, copies included
        res, status = self.lists(rows, okr, np.zeros(self.n, dtype=bool), np.where(ok, kc, 0))
        flagged = np.zeros(c, dtype=bool)  # clusters with copies (a zero distance), done again below
        flagged[ginv[rows[status == 2]]] = True
        self.store_lists(rows, res, ~flagged[ginv[rows]])
        tied = rows[(status == 1) & ~flagged[ginv[rows]]]
        n_tree = len(tied)
        if len(tied):
            self.store(knn_query(g, ginv, rows, kc, self.threads, query=np.searchsorted(rows, tied), extra=SPARE)[0])
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
                    n_tree += len(rows2)
                    self.store(knn_query(g, ginv, rows2, k2, self.threads, extra=SPARE)[0])
                else:
                    self.store_lists(rows2, res, np.ones(len(rows2), dtype=bool))
                    tied = rows2[status == 1]
                    n_tree += len(tied)
                    if len(tied):
                        self.store(knn_query(g, ginv, rows2, k2, self.threads, query=np.searchsorted(rows2, tied),
                                             extra=SPARE)[0])
        has = self.kk > 0
        self.kcl[ginv[has]] = self.kk[has]
        logger.debug("first k-NN lists for %d points (%d asked of the k-d tree); %d clusters with copies",
                     int(has.sum()), n_tree, int(flagged.sum()))

    def lists(self, q, member, dup, kcl):
        """Lists of the rows q (ascending) among the ``member``, non-``dup`` rows of their cluster, k = kcl.

        By :func:`.kernels.lists.refresh_lists` on the threads; returns (each range's results with its q), status (len(q),) int8.
        """
        cut = np.searchsorted(q, [r[3] for r in self.chunks.ranges] + [self.n])  # q of each range
        res = self.chunks.map(lambda i, c0, c1, a, b: (q[cut[i] : cut[i + 1]],) + kl.refresh_lists(
            self.g, self.ginv, self.chunks.starts, member, dup, q[cut[i] : cut[i + 1]], kcl, SPARE,
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
        test = RoundTest(rule, threshold, target, coverage)
        while max_rounds is None or rnd < max_rounds:
            # ties: canonical index (the input order, not the grouped one)
            sel = round_selection(self.g, alive, self.val, self.order, self.nbx, n_alive, test, self.kk, self.r1,
                                  self.chunks)
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
        """New k-NN lists for rows q (ascending): by :meth:`lists`, tied rows by the k-d tree of a query of all q."""
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
                                 extra=SPARE)[0])
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
            # the terms of .kernels.entropy.entropy_weights, with numpy's log and exp
            lw, lw1 = ks.log_weights(rows, ginv, c0, c1, np.log(self.rk[rows]), np.log(self.rk1[rows]), neg_dim)
            dW, dG, Wc = ks.entropy_deltas(rows, ginv, c0, c1, kk, self.nbx, np.exp(lw), np.exp(lw1), lw, lw1,
                                           self.acc_w, self.acc_g)
            ks.store_scores(rows, ginv, np.abs(entropy_change(dW, dG, Wc)), m, use_unit, self.val)

        self.chunks.map(part)
