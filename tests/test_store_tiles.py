"""Out-of-core grouping by key (store/buckets.py) on a real scan, against an in-memory groupby oracle."""

from __future__ import annotations

import pickle
from functools import partial

import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.engine.runner import Runner
from cloudsieve.errors import ArrayNotFoundError, InvalidParameterError
from cloudsieve.store import ingest
from cloudsieve.store.buckets import Buckets, bucket


def grid_keys(xyz: np.ndarray, size: float) -> np.ndarray:
    """A square grid's cell of each point (module level: pickled into the tasks)."""
    ij = np.floor(xyz[:, :2] / size).astype(np.int64)
    return ij[:, 0] * 1_000_003 + ij[:, 1]


def bad_keys(xyz: np.ndarray) -> np.ndarray:
    return np.zeros(len(xyz) + 1, dtype=np.int64)


def float_keys(xyz: np.ndarray) -> np.ndarray:
    return xyz[:, 0]


@pytest.fixture
def autzen(tmp_path):
    """autzen_trim.laz (110 000 points) in a store of 16 000-point chunks (the last one partial), with a mask."""
    store = ingest(shared_file("autzen_trim.laz"), tmp_path / "s.zarr", chunk_size=16_000)
    keep = np.random.default_rng(7).random(store.count) < 0.6
    store.create_array("simplify/keep", data=keep)
    return store, keep


def oracle(store, keep, size):
    """Every attribute of the kept points grouped by key, in memory: {key: {name: array}} in input order."""
    parts = [arrays for _, arrays in store.chunks()]
    cloud = {n: np.concatenate([p[n] for p in parts])[keep] for n in parts[0]}
    keys = grid_keys(cloud["xyz"], size)
    order = np.argsort(keys, kind="stable")
    uniq, first, counts = np.unique(keys[order], return_index=True, return_counts=True)
    groups = {int(k): {n: v[order[a:a + c]] for n, v in cloud.items()} for k, a, c in zip(uniq, first, counts)}
    return uniq, counts, groups


@pytest.mark.parametrize("runner", [None, "threads"])
def test_bucket_matches_groupby_oracle(autzen, runner):
    store, keep = autzen
    run = Runner("threads", workers=2) if runner else None
    try:
        b = bucket(store, partial(grid_keys, size=150.0), "grid", mask="simplify/keep", run=run)
    finally:
        if run is not None:
            run.close()
    uniq, counts, groups = oracle(store, keep, 150.0)
    np.testing.assert_array_equal(b.keys, uniq)
    np.testing.assert_array_equal(b.counts, counts)
    assert b.keys.dtype == np.int64 and b.counts.dtype == np.int64
    assert int(b.counts.sum()) == int(keep.sum())
    assert b.names == store.dimensions
    for k in b.keys:
        got = b.read(k)
        assert list(got) == store.dimensions
        for name, want in groups[int(k)].items():
            assert got[name].dtype == want.dtype
            np.testing.assert_array_equal(got[name], want, err_msg=f"key {k}, {name}")
    assert len(b) == len(uniq) > 10


def test_bucket_all_points_blocks_and_reopen(autzen):
    store, _ = autzen
    b = bucket(store.path, partial(grid_keys, size=400.0), "all")
    uniq, counts, groups = oracle(store, np.ones(store.count, bool), 400.0)
    np.testing.assert_array_equal(b.counts, counts)
    assert int(b.counts.sum()) == store.count
    big = int(b.keys[np.argmax(b.counts)])
    runs = b.runs(big)
    assert runs.shape[1] == 3 and np.all(np.diff(runs[:, 0]) > 0)  # one run per chunk, chunks increasing
    blocks = list(b.blocks(big, 5_000))
    assert len(blocks) > 1 and all(len(x["xyz"]) <= 16_000 for x in blocks)
    for name, want in groups[big].items():
        np.testing.assert_array_equal(np.concatenate([x[name] for x in blocks]), want)
    # reopened and unpickled, it reads the same
    again = pickle.loads(pickle.dumps(b))
    same = Buckets.open(store.path, "all")
    for other in (again, same):
        np.testing.assert_array_equal(other.keys, b.keys)
        np.testing.assert_array_equal(other.read(big)["gps_time"], groups[big]["gps_time"])
    # a key without points
    missing = b.read(int(b.keys.max()) + 1)
    assert missing["xyz"].shape == (0, 3) and missing["intensity"].shape == (0,)
    assert list(b.blocks(int(b.keys.max()) + 1, 10)) == []
    b.delete()
    assert "export/all" not in store.group
    with pytest.raises(ArrayNotFoundError, match=r"holds no complete buckets 'all' \(no export/all/keys\)"):
        Buckets.open(store.path, "all")


def test_bucket_errors(autzen):
    store, _ = autzen
    store.create_array("simplify/rank", data=np.arange(store.count))
    with pytest.raises(InvalidParameterError, match=r"mask 'simplify/rank' must be boolean, got dtype int64"):
        bucket(store, partial(grid_keys, size=100.0), "x", mask="simplify/rank")
    with pytest.raises(ArrayNotFoundError, match=r"has no array 'simplify/nothing'"):
        bucket(store, partial(grid_keys, size=100.0), "x", mask="simplify/nothing")
    with pytest.raises(InvalidParameterError, match=r"keys\(16000 points\) must return an integer array of shape "
                                                    r"\(16000,\), got int64 \(16001,\)"):
        bucket(store, bad_keys, "x")
    with pytest.raises(InvalidParameterError, match=r"got float64 \(16000,\)"):
        bucket(store, float_keys, "x")
    with pytest.raises(InvalidParameterError, match=r"bucket name must be a non-empty name without '/', got 'a/b'"):
        bucket(store, float_keys, "a/b")
