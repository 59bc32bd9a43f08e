"""The elimination's neighbour lists (core/kernels/neighbours.py): build_lists against a slow obvious
oracle (every alive point within 2 r_max in grid-walk order, sorted by distance then tie), bit for bit,
on one thread and on several."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from cloudsieve.core.cellgrid import CellGrid
from cloudsieve.core.kernels import neighbours as kn
from cloudsieve.core.relocate import numba_threads


def oracle(grid, state, two_r, alpha, ialpha):
    """The lists row by row in Python, the kernel's arithmetic in its order."""
    P, cell, cstart, nstart, ncells = grid.args()
    inv2r = 1.0 / two_r
    nptr, nbr, low, term, soff, w = [0], [], [], [], [], np.zeros(len(P))
    for i in range(len(P)):
        if state[i]:
            found = []
            for cc in ncells[nstart[cell[i]] : nstart[cell[i] + 1]]:
                for j in range(cstart[cc], cstart[cc + 1]):
                    if j != i and state[j]:
                        dx, dy, dz = P[j, 0] - P[i, 0], P[j, 1] - P[i, 1], P[j, 2] - P[i, 2]
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 < two_r * two_r:
                            found.append((j, d2))
            s = 0.0
            for j, d2 in found:
                u = kn.ipow(1.0 - math.sqrt(d2) * inv2r, alpha, ialpha)
                s += u
                nbr.append(j)
                term.append(u)
                low.append(np.float32(u * kn.SHRINK) if u > kn.TINY else np.float32(0.0))
            w[i] = s
            soff += sorted(range(len(found)), key=lambda t: (found[t][1], grid.order[found[t][0]]))
        nptr.append(len(nbr))
    return np.array(nptr), np.array(nbr), np.array(low, dtype=np.float32), np.array(soff), w, np.array(term)


@pytest.mark.parametrize("case", ["sheet", "copies and a dense spot", "very dense", "empty"])
@pytest.mark.parametrize("alpha", [1.0, 2.5])
def test_lists_equal_the_oracle_on_any_thread_count(case, alpha):
    rng = np.random.default_rng(3)
    pts = np.round(np.c_[rng.random((3000, 2)) * 20, rng.random(3000) * 0.2], 2)
    if case == "copies and a dense spot":  # lists longer than 32 (a merge sort) and ties of distance
        pts = np.concatenate([pts, np.repeat(pts[:3], 50, axis=0), np.round(rng.random((300, 3)) * 0.3, 2)])
    elif case == "very dense":  # lists longer than 256 (uint16 positions); buffers of 8 a point grown
        pts = np.round(rng.random((1200, 3)) * 0.5, 3)
    elif case == "empty":
        pts = np.zeros((0, 3))
    two_r = 0.6
    grid = CellGrid(pts, two_r)
    state = np.ones(len(pts), dtype=np.uint8)
    state[grid.copy] = 0
    state[rng.random(len(pts)) < 0.1] = 0
    ialpha = int(alpha) if alpha == int(alpha) else -1
    want = oracle(grid, state, two_r, alpha, ialpha)
    if case == "very dense":
        assert np.diff(want[0]).max() > 256 and len(want[1]) > 8 * len(pts) + 64
    for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):  # ranges of 500 rows: several
        for nearest_first in (True, False):
            with numba_threads(threads):
                got = kn.build_lists(*grid.args(), grid.order, state, two_r, alpha, ialpha, nearest_first, rows=500)
            nptr, nbr, low, soff, w, term = got
            assert nptr.tolist() == want[0].tolist() and nbr.tolist() == want[1].tolist()
            assert nbr.dtype == kn.index_type(len(pts))
            assert low.tobytes() == want[2].tobytes() and w.tobytes() == want[4].tobytes()
            assert term.tobytes() == want[5].tobytes()
            longest = int(np.diff(nptr).max(initial=0))
            assert soff.dtype == (np.uint8 if longest <= 256 else np.uint16)
            if nearest_first:
                assert soff.tolist() == want[3].tolist()
            else:
                assert soff.tolist() == [0]
