"""The partition's uniform sample: its size, its rows (drawn once from the seed, independent of the
chunking), read by one task per chunk (:func:`sample_chunk`) or picked during the ingest (:class:`IngestSample`)."""

from __future__ import annotations

import numpy as np

__all__ = ["n_cells_for", "sample_size", "plan_sample", "sample_chunk", "IngestSample"]


def n_cells_for(n: int, cell_size: int) -> int:
    """P = ceil(N / cell_size), at least 1."""
    return max(1, -(-int(n) // int(cell_size)))


def sample_size(n: int, n_cells: int) -> int:
    """Points in the uniform sample the centres are fitted on."""
    return int(min(n, max(50_000, 256 * n_cells), 1_000_000))


def plan_sample(n: int, n_cells: int, seed: int) -> np.ndarray:
    """Sorted indices (S,) int64 of the uniform sample, drawn from (seed, "partition")."""
    s = sample_size(n, n_cells)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x9A27]))
    if s >= n:
        return np.arange(n, dtype=np.int64)
    return np.sort(rng.choice(n, size=s, replace=False)).astype(np.int64)


class IngestSample:
    """The partition's sample, taken while the ingest writes the store (its ``on_chunk``).

    Its rows are :func:`plan_sample`'s for the reader's announced count, so
    when no point is dropped it equals the sample :func:`build_partition`
    would read, and the partition skips its sample stage. *cell_size*,
    *seed*: as given to :func:`build_partition`.
    """

    def __init__(self, cell_size: int, seed: int) -> None:
        self.cell_size, self.seed = int(cell_size), int(seed)
        self.count: int | None = None
        self.rows = np.empty(0, dtype=np.int64)
        self.parts: list[np.ndarray] = []

    def __call__(self, start: int, xyz: np.ndarray, count: int | None) -> None:
        if self.count is None:
            self.count = int(count or 0)
            if self.count:
                self.rows = plan_sample(self.count, n_cells_for(self.count, self.cell_size), self.seed)
        a, b = np.searchsorted(self.rows, [start, start + len(xyz)])
        if b > a:
            self.parts.append(xyz[self.rows[a:b] - start])

    def sample(self, n: int) -> np.ndarray | None:
        """The sample of the store of *n* points, or None when it was planned for another count."""
        got = sum(len(p) for p in self.parts)
        if self.count != n or got != len(self.rows):
            return None
        return np.concatenate(self.parts, axis=0) if self.parts else np.empty((0, 3))


def sample_chunk(store_path: str, start: int, stop: int, indices: np.ndarray) -> np.ndarray:
    """Task: coordinates (len(indices), 3) float64 of the sample points in ``[start, stop)``."""
    from ..store import PointStore

    if len(indices) == 0:
        return np.empty((0, 3))
    st = PointStore.open(store_path, "r")
    xyz = st.read("xyz", start, stop)
    return xyz[np.asarray(indices) - start]
