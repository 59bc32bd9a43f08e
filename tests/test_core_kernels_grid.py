"""The elimination's grid (core/kernels/grid.py): the 27-cell neighbour lists against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.kernels import grid as kg


def brute_neighbours(ukeys):
    """For each cell, the occupied cells whose integer coordinates differ by at most 1, in (dx, dy, dz) order."""
    q = np.array([[kg._compact(int(k) >> a) for a in range(3)] for k in ukeys], dtype=np.int64).reshape(-1, 3)
    at = {tuple(v): c for c, v in enumerate(q.tolist())}
    nstart, out = [0], []
    for v in q.tolist():
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    c = at.get((v[0] + dx, v[1] + dy, v[2] + dz))
                    if c is not None:
                        out.append(c)
        nstart.append(len(out))
    return nstart, out


@pytest.mark.parametrize("case", ["sheet", "far apart", "one", "none"])
def test_cell_neighbours_equal_brute_force(case):
    rng = np.random.default_rng(7)
    pts = {"sheet": np.c_[rng.random((3000, 2)) * 40, rng.random(3000)],
           "far apart": np.r_[rng.random((300, 3)), rng.random((300, 3)) * 1e6],
           "one": np.zeros((1, 3)), "none": np.zeros((0, 3))}[case]
    ukeys = np.unique(kg.cell_codes(pts, pts.min(axis=0) if len(pts) else np.zeros(3), 1.0))  # sorted, distinct
    expected = brute_neighbours(ukeys)
    nstart, ncells = kg.cell_neighbours(ukeys)
    assert nstart.tolist() == expected[0] and ncells.tolist() == expected[1]
