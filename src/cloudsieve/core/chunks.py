"""Ranges of clusters for the threads of the rounds' kernels (DESIGN.md stage 5).

No kernel crosses a cluster, so disjoint ranges run on threads and no result
depends on the thread count.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["ClusterChunks"]


class ClusterChunks:
    """Ranges of clusters of about equal point counts: one without a pool, else four per thread.

    ``starts`` (c + 1,): cluster j is rows starts[j] to starts[j + 1]. ``ranges``: list
    of (i, c0, c1, a, b), range i holding clusters c0 to c1 - 1, rows a to b - 1.
    """

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
        """[fn(i, c0, c1, a, b) for each range], run on the pool, in range order."""
        if self.pool is None:
            return [fn(*r) for r in self.ranges]
        return list(self.pool.map(lambda r: fn(*r), self.ranges))
