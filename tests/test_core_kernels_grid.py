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


@pytest.mark.parametrize("case", ["sheet", "far apart", "corners", "one", "none"])
def test_cell_neighbours_equal_brute_force(case):
    rng = np.random.default_rng(7)
    top = 2.0**21 - 2  # "corners": a box of 2^63 cells, too many for the dense keys (the lexicographic ones)
    pts = {"sheet": np.c_[rng.random((3000, 2)) * 40, rng.random(3000)],
           "far apart": np.r_[rng.random((300, 3)), rng.random((300, 3)) * 1e6],
           "corners": np.array([[0.0, 0.0, 0.0], [top, top, top], [0.0, top, 5.0], [1.0, 0.0, 0.0]]),
           "one": np.zeros((1, 3)), "none": np.zeros((0, 3))}[case]
    ukeys = np.unique(kg.cell_codes(pts, pts.min(axis=0) if len(pts) else np.zeros(3), 1.0))  # sorted, distinct
    expected = brute_neighbours(ukeys)
    nstart, ncells = kg.cell_neighbours(ukeys)
    assert nstart.tolist() == expected[0] and ncells.tolist() == expected[1]


@pytest.mark.parametrize("case", ["few values", "wide", "zeros", "one", "none"])
def test_argsort_keys_is_numpys_stable_argsort(case):
    rng = np.random.default_rng(3)
    key = {"few values": rng.integers(0, 5, 5000), "wide": rng.integers(0, 2**62, 5000),
           "zeros": np.zeros(100, dtype=np.int64), "one": np.array([7]), "none": np.zeros(0, dtype=np.int64)}[case]
    key = np.asarray(key, dtype=np.int64)
    assert kg.argsort_keys(key).tolist() == np.argsort(key, kind="stable").tolist()


@pytest.mark.parametrize("rows", ["all", "some"])
def test_nearest_kept_with_piles_of_copies_equals_brute_force(rows):
    """CellGrid.nearest_kept searches once per group of exact copies (a pile of m copies searched row by row
    costs m^2): the same answers as a brute-force search of every row (nearest kept point of the 27 cells,
    equal distances lower tie)."""
    from cloudsieve.core.cellgrid import CellGrid

    rng = np.random.default_rng(11)
    pts = np.round(np.c_[rng.random((2000, 2)) * 10, rng.random(2000) * 0.1], 2)
    pts = np.concatenate([pts, np.repeat(pts[:3], 400, axis=0), pts[rng.integers(0, 2000, 300)]])  # piles
    pts = pts[rng.permutation(len(pts))]
    grid = CellGrid(pts, 0.5)
    kept = (rng.random(len(pts)) < 0.3).astype(np.uint8)
    kept[grid.lead[grid.order == 0]] = 1  # some kept rows in piles, some piles with none kept
    which = np.arange(len(pts)) if rows == "all" else np.flatnonzero(rng.random(len(pts)) < 0.4)
    assert grid.copy[which].sum() > 400
    got = grid.nearest_kept(kept, which)
    P, cell = grid.P, grid.cell
    for u, p in enumerate(which):
        near = np.concatenate([np.arange(grid.cstart[c], grid.cstart[c + 1])
                               for c in grid.ncells[grid.nstart[cell[p]] : grid.nstart[cell[p] + 1]]])
        near = near[kept[near] != 0]
        if not len(near):
            assert got[u] == -1
            continue
        d2 = ((P[near] - P[p]) ** 2).sum(axis=1)
        best = near[np.lexsort((grid.order[near], d2))[0]]
        assert got[u] == best


@pytest.mark.parametrize("case", ["sparse", "piles", "dense"])
def test_grid_order_is_the_lexsort_oracle(case):
    """CellGrid's internal order: by cell code, then coordinates, then index (insertion sort inside short
    runs, a lexsort inside each long one), whatever the input order."""
    from cloudsieve.core.cellgrid import CellGrid

    rng = np.random.default_rng(12)
    pts = np.round(rng.random((3000, 3)) * [20, 20, 1], 2)
    if case == "piles":
        pts = np.concatenate([pts, np.repeat(pts[:4], 200, axis=0)])
    h = {"sparse": 1.0, "piles": 1.0, "dense": 5.0}[case]  # dense: every cell holds more than 64 points
    pts = pts[rng.permutation(len(pts))]
    grid = CellGrid(pts, h)
    codes = kg.cell_codes(pts, pts.min(axis=0), grid.h)
    assert grid.order.tolist() == np.lexsort((np.arange(len(pts)), pts[:, 2], pts[:, 1], pts[:, 0], codes)).tolist()
    lead, last = [], 0
    for i, c in enumerate(grid.copy.tolist()):
        last = last if c else i
        lead.append(last)
    assert grid.lead.tolist() == lead
