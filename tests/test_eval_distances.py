"""Per-chunk distances: partial statistics combine the same in any grouping (point_errors itself: test_eval_points.py)."""

from __future__ import annotations

import numpy as np

from cloudsieve.evaluate.distances import Target, combine, forward_chunk


def test_chunk_combine_any_grouping():
    rng = np.random.default_rng(6)
    a = rng.random((3000, 3))
    t = Target(a[::2])
    parts = [forward_chunk(a[i : i + 500], t)[0] for i in range(0, 3000, 500)]
    left = combine([combine(parts[:2]), combine(parts[2:])])
    flat = combine(parts)
    assert left["count"] == flat["count"] == 3000
    assert left["max"] == flat["max"]
    assert np.array_equal(left["hist"], flat["hist"])
    assert np.array_equal(left["matched"], flat["matched"])
