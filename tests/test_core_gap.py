"""The gap bound's fill on one cell (core/gap.py, core/kernels/gapfill.py) against slow obvious oracles.

The greedy cover against a brute-force sequential cover (every earlier added
point tested); the fill of a cell: every point within D of the kept, known
and added points; every added point farther than D from all kept and known
points and from every point added before it in the fill's order
(farthest first, ties by row); copies added with their point under
``keep_duplicates``.
"""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.gap import cell_gap, fill_cell
from cloudsieve.core.kernels.gapfill import greedy_cover


def brute_cover(P: np.ndarray, gap: float) -> np.ndarray:
    added = np.zeros(len(P), dtype=bool)
    for i in range(len(P)):  # the oracle: slow on purpose
        earlier = P[:i][added[:i]]
        added[i] = not len(earlier) or np.sqrt(((earlier - P[i]) ** 2).sum(axis=1)).min() > gap
    return added


def nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from each row of *a* to the nearest row of *b*, by all pairs."""
    if not len(b):
        return np.full(len(a), np.inf)
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2)).min(axis=1)


@pytest.mark.parametrize("seed, gap", [(0, 0.05), (1, 0.12), (2, 0.3), (3, 1e-3)])
def test_the_greedy_cover_is_the_brute_force_one(seed, gap):
    P = np.random.default_rng(seed).random((700, 3)) * [1.0, 1.0, 0.2]
    q = np.floor((P - P.min(axis=0)) / gap).astype(np.int64)
    u, cell = np.unique(q, axis=0, return_inverse=True)
    got = greedy_cover(P, q, cell.reshape(-1).astype(np.int64), u, gap)
    assert np.array_equal(got, brute_cover(P, gap))


@pytest.mark.parametrize("seed, share, gap", [(0, 0.1, 0.08), (1, 0.02, 0.15), (2, 0.3, 0.05), (3, 0.0, 0.2)])
def test_a_filled_cell_is_within_the_bound_and_its_fill_is_the_greedy_one(seed, share, gap):
    rng = np.random.default_rng(seed)
    core = rng.random((900, 3)) * [1.0, 1.0, 0.1]
    keep = rng.random(900) < share
    known = rng.random((40, 3)) * [1.0, 1.0, 0.1] + [0.8, 0.0, 0.0]  # a neighbour's kept points, overlapping
    fill = fill_cell(core, keep, known, gap, False)
    assert not (fill & keep).any()
    assert nearest(core, np.concatenate([core[keep | fill], known])).max() <= gap
    # the order: farthest from the kept and known points first, ties by row; each added unless covered
    d = nearest(core, np.concatenate([core[keep], known]))
    far = np.flatnonzero(d > gap)
    far = far[np.lexsort((far, -d[far]))]
    want = np.zeros(900, dtype=bool)
    want[far[brute_cover(core[far], gap)]] = True
    assert np.array_equal(fill, want)
    assert cell_gap(core, np.concatenate([core[keep | fill], known])) == pytest.approx(
        nearest(core, np.concatenate([core[keep | fill], known])).max(), rel=1e-12)


def test_copies_of_an_added_point_are_added_with_keep_duplicates():
    rng = np.random.default_rng(5)
    base = rng.random((200, 3))
    core = np.concatenate([base, base[:50], base[:10]])  # rows 200-249 copy rows 0-49, 250-259 rows 0-9
    keep = np.zeros(len(core), dtype=bool)
    keep[rng.choice(200, 20, replace=False)] = True
    keep[200:250] |= keep[:50]  # the elimination keeps every copy of a kept point
    keep[250:260] |= keep[:10]
    plain = fill_cell(core, keep, np.empty((0, 3)), 0.1, False)
    copies = fill_cell(core, keep, np.empty((0, 3)), 0.1, True)
    first = np.r_[np.arange(200), np.arange(50), np.arange(10)]
    assert np.array_equal(copies, np.isin(first, first[plain]) & ~keep)
    assert (copies.sum() > plain.sum()) and not (plain & ~copies).any()


def test_nothing_to_fill_and_no_point():
    core = np.random.default_rng(0).random((50, 3))
    assert not fill_cell(core, np.ones(50, dtype=bool), np.empty((0, 3)), 0.01, False).any()
    assert fill_cell(np.empty((0, 3)), np.zeros(0, dtype=bool), np.empty((0, 3)), 0.1, False).shape == (0,)
    assert cell_gap(np.empty((0, 3)), core) == 0.0
    assert cell_gap(core, np.empty((0, 3))) == np.inf
    one = fill_cell(core, np.zeros(50, dtype=bool), np.empty((0, 3)), 10.0, False)
    assert one.sum() == 1  # the farthest from nothing: every distance inf, so the first row
