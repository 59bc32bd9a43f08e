"""The colours of the cells (pass 2 of the eliminate rule): a proper, deterministic greedy colouring."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.core.colours import cell_colours, halo_graph
from cloudsieve.errors import InvalidParameterError


def csr(p, pairs):
    pairs = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    ptr = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=p), out=ptr[1:])
    return ptr, pairs[:, 1]


def test_the_graph_is_symmetric_without_self_loops():
    ptr, nbr = halo_graph(*csr(4, [(0, 0), (0, 1), (2, 1), (3, 0)]))
    assert [nbr[ptr[i] : ptr[i + 1]].tolist() for i in range(4)] == [[1, 3], [0, 2], [1], [0]]


def test_a_path_a_triangle_and_isolated_cells():
    assert cell_colours(*csr(3, [(0, 1), (1, 2)])).tolist() == [1, 0, 1]
    assert sorted(cell_colours(*csr(3, [(0, 1), (1, 2), (2, 0)])).tolist()) == [0, 1, 2]
    assert cell_colours(*csr(3, [])).tolist() == [0, 0, 0]
    assert cell_colours([0], []).tolist() == []


def test_random_graphs_are_coloured_properly_and_by_degree_then_id():
    rng = np.random.default_rng(5)
    for _ in range(20):
        p = int(rng.integers(2, 60))
        pairs = {tuple(map(int, rng.integers(0, p, 2))) for _ in range(3 * p)}
        ptr, src = csr(p, pairs)
        col = cell_colours(ptr, src)
        a, b = halo_graph(ptr, src)
        rows = np.repeat(np.arange(p), np.diff(a))
        assert np.all(col[rows] != col[b])  # neighbours differ
        deg = np.diff(a)
        assert col.max() <= deg.max()  # greedy: at most max degree + 1 colours
        assert col[np.lexsort((np.arange(p), -deg))[0]] == 0  # the first cell of the order gets colour 0
        assert np.array_equal(col, cell_colours(ptr.copy(), src.copy()))


@pytest.mark.parametrize("ptr, src, match", [
    ([1, 2], [0], "CSR pointer from 0"),
    ([0, 2], [0], "CSR pointer from 0"),
    ([0, 1, 1], [2], r"cells in \[0, 2\)"),
])
def test_bad_graphs_are_refused(ptr, src, match):
    with pytest.raises(InvalidParameterError, match=match):
        cell_colours(ptr, src)
