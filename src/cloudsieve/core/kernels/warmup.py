"""Compile the kernels of the scoring path once per process tree, before forking workers.

numba compiles a kernel at its first call, or loads it from its on-disk cache
(``cache=True``: ``__pycache__`` beside the module, or numba's user cache
directory when that is read-only). Measured on this 2-core machine (load ~5):
the first k-NN call of a fresh process takes ~11-12 s without the cache and
~0.5 s with it, the entropy kernels ~2.6 s and ~0.05 s. The local fork server
(:mod:`cloudsieve.engine.forkserver_init`) calls :func:`warm_up` once, so the
worker processes it forks, replaced every few tasks, inherit the compiled code
and never load or compile it again.
"""

from __future__ import annotations

import time

import numpy as np

from .copies import first_equal
from .entropy import entropy_gain, graph_to_input, grouped_gain, reverse_sums, scores_to_input
from .knn import knn_scored, knn_unchecked, take_neighbours
from .order import grouped_order
from .scatter import from_groups

__all__ = ["warm_up"]


def warm_up() -> float:
    """Call each kernel of the scoring path once on a tiny input, with the argument types
    of the real calls (so the same compiled versions); one thread. Returns the seconds spent."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    P = np.ascontiguousarray(rng.random((24, 3)))
    indptr = np.array([0, 12, 24], dtype=np.int64)
    kq = np.array([5, 5], dtype=np.int64)
    d, i = knn_unchecked(P, indptr, kq, np.ones(24, dtype=bool), 1)
    rows = np.arange(24, dtype=np.int64)
    take_neighbours(i, rows, 5)
    take_neighbours(i, rows, 5, rows)
    cl = np.repeat(np.arange(2, dtype=np.int64), 12)
    nbr = np.ascontiguousarray(i[:, :5])
    kr = np.full(24, 4, dtype=np.int64)
    entropy_gain(rows, cl, 2, d[:, 3].copy(), d[:, 4].copy(), nbr, kr, 3.0, 24)
    entropy_gain(rows, cl, 2, d[:, 3].copy(), d[:, 4].copy(), nbr, kr, 3.0, 24, target_cluster=cl)
    reverse_sums(nbr, kr, d[:, 0].copy(), d[:, 1].copy(), 24)
    # the path of the scores without context (entropy.score_unchecked)
    order, indptr = grouped_order(P, cl, 2, 17)
    kcl = np.array([4, 4], dtype=np.int64)
    koff = np.array([0, 48, 96], dtype=np.int64)
    rk, rk1, nb, _ = knn_scored(P, order, indptr, kcl, koff, 1)
    scored = np.ones(24, dtype=bool)
    gain = grouped_gain(rk, rk1, indptr, kcl, koff, scored, nb, 3.0)
    scores_to_input(order, indptr, kcl, scored, ~scored, np.array([12, 12]), gain)
    graph_to_input(order, indptr, kcl, koff, scored, nb, 4)
    first_equal((P + 0.0).view(np.uint64))  # exact copies (every rule's cells)
    from_groups(np.zeros(2, dtype=np.int32), np.zeros(1, dtype=np.int64), np.ones(2, dtype=bool))  # the merge
    return time.perf_counter() - t0
