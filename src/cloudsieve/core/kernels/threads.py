"""Threads for the compiled kernels (they release the GIL): a leaf of plain Python.

Kernels write only their own rows or clusters, so results do not depend on the thread count.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["Chunks", "run_chunks"]


class Chunks:
    """Runs a function of a row range over [0, n) in chunks on ``threads`` threads (a context manager)."""

    def __init__(self, threads: int):
        self.threads = max(1, int(threads))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown()

    def map(self, fn, n: int, min_chunk: int = 4096) -> list:
        """[fn(s, e) for consecutive ranges covering [0, n)], in range order."""
        if self._pool is None or n <= min_chunk:
            return [fn(0, n)]
        step = max(min_chunk, -(-n // (4 * self.threads)))
        return self.each(lambda s: fn(s, min(n, s + step)), range(0, n, step))

    def each(self, fn, items) -> list:
        """[fn(x) for x in items], in order, on the threads."""
        if self._pool is None:
            return [fn(x) for x in items]
        return list(self._pool.map(fn, items))


def run_chunks(fn, indptr, threads, *args):
    """fn(*args[:3], c0, c1, *args[3:]) over chunks of clusters of about equal point counts, on threads."""
    n = int(indptr[-1])
    c = len(indptr) - 1
    threads = max(1, int(threads or os.cpu_count() or 1))
    parts = 1 if threads == 1 else min(c, 4 * threads)
    cuts = np.unique(np.searchsorted(indptr, np.linspace(0, n, parts + 1)[1:-1]))
    bounds = np.r_[0, cuts[(cuts > 0) & (cuts < c)], c]
    if len(bounds) == 2:
        fn(*args[:3], 0, c, *args[3:])
        return
    with ThreadPoolExecutor(min(threads, len(bounds) - 1)) as pool:
        for f in [pool.submit(fn, *args[:3], int(a), int(b), *args[3:]) for a, b in zip(bounds[:-1], bounds[1:])]:
            f.result()
