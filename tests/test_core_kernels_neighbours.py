"""The elimination's neighbour lists (core/kernels/neighbours.py): the one-pass builder (one thread, the
engine's cells) gives the three parallel passes' arrays bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.cellgrid import CellGrid
from cloudsieve.core.kernels import neighbours as kn


@pytest.mark.parametrize("case", ["sheet", "copies and a dense spot", "very dense", "empty"])
@pytest.mark.parametrize("alpha", [1.0, 2.5])
@pytest.mark.parametrize("nearest_first", [True, False])
def test_one_pass_lists_equal_the_three_passes(case, alpha, nearest_first):
    rng = np.random.default_rng(3)
    pts = np.round(np.c_[rng.random((4000, 2)) * 20, rng.random(4000) * 0.2], 2)
    if case == "copies and a dense spot":  # lists longer than 32 (sorted as sort_lists does) and ties
        pts = np.concatenate([pts, np.repeat(pts[:3], 50, axis=0), np.round(rng.random((400, 3)) * 0.3, 2)])
    elif case == "very dense":  # lists longer than 256: uint16 positions
        pts = np.round(rng.random((1500, 3)) * 0.5, 3)
    elif case == "empty":
        pts = np.zeros((0, 3))
    two_r = 0.6
    grid = CellGrid(pts, two_r)
    state = np.ones(len(pts), dtype=np.uint8)
    state[grid.copy] = 0
    state[rng.random(len(pts)) < 0.1] = 0
    ialpha = int(alpha) if alpha == int(alpha) else -1
    args = (*grid.args(), grid.order, state, two_r, alpha, ialpha, nearest_first)
    ref = kn.three_pass_lists(*args)
    longest = int(np.diff(ref[0]).max(initial=0))
    if case == "very dense":  # lists longer than 256 (uint16 positions), 8 a point's buffers grown
        assert longest > 256 and ref[3].dtype == np.uint16 and len(ref[1]) > 8 * len(pts) + 64
    from cloudsieve.core.relocate import numba_threads

    with numba_threads(1):  # build_lists takes the one pass with one thread
        out = kn.build_lists(*args)
    for got, want in zip(out, ref):
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
