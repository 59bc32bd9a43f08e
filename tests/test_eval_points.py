"""Point-level errors: brute-force oracles, streaming, sampling, dask, stores."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.distance import cdist

from cloudsieve.errors import EmptyInputError, NotASubsetError
from cloudsieve.evaluate.points import PointLevel, point_errors
from cloudsieve.engine.runner import NO_HTTP_PORT


def _brute(a, b):
    d = cdist(a, b)
    return d.min(axis=1), d.min(axis=0)


def _check_against(r, f, bk, diag):
    for name, d in (("forward", f), ("backward", bk)):
        x = r[name]
        assert x["count"] == len(d)
        assert_allclose(x["mean"], d.mean(), rtol=1e-12, atol=1e-15)
        assert_allclose(x["rms"], np.sqrt((d**2).mean()), rtol=1e-12, atol=1e-15)
        assert x["max"] == pytest.approx(d.max(), rel=1e-12, abs=1e-15)
        assert_allclose(x["mean_pct"], 100 * d.mean() / diag, rtol=1e-12, atol=1e-15)
        assert_allclose(x["max_pct"], 100 * d.max() / diag, rtol=1e-12, atol=1e-15)
        assert x["zeros"] == int((d == 0).sum())
    assert r["hausdorff"] == pytest.approx(max(f.max(), bk.max()), rel=1e-12)


def test_hand_made_sets_exact_values():
    a = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]], float)
    b = np.array([[0, 0, 0], [1, 0, 1]], float)
    r = point_errors(a, b)
    # forward: 0, 1, 2, sqrt(1+9)... nearest of (0,0,3): (0,0,0) at 3 or (1,0,1) at sqrt(5)
    f = np.array([0.0, 1.0, 2.0, np.sqrt(5.0)])
    bk = np.array([0.0, 1.0])
    diag = np.sqrt(1 + 4 + 9)
    _check_against(r, f, bk, diag)
    assert r["diagonal"] == pytest.approx(diag)
    assert r["subset"] is False and r["not_in_original"] == 1
    assert r["mode"] == "exact"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_sets_equal_brute_force(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(1500, 3)) * [3, 1, 0.2]
    b = np.concatenate([a[rng.choice(1500, 300, replace=False)], rng.normal(size=(40, 3))])
    f, bk = _brute(a, b)
    r = point_errors(a, b, PointLevel(chunk_size=256))
    diag = np.linalg.norm(a.max(0) - a.min(0))
    _check_against(r, f, bk, diag)
    assert r["not_in_original"] == 40


def test_streamed_equals_in_memory():
    rng = np.random.default_rng(5)
    a = rng.random((20_000, 3))
    b = np.concatenate([a[::3], rng.random((100, 3))])
    one = point_errors(a, b, PointLevel(chunk_size=len(a)))
    many = point_errors(a, b, PointLevel(chunk_size=997))
    for name in ("forward", "backward"):
        for key in ("count", "max", "zeros"):
            assert one[name][key] == many[name][key]
        for key in ("mean", "rms"):
            assert_allclose(one[name][key], many[name][key], rtol=1e-12)
    assert one["histogram"] == many["histogram"]
    assert one["bounds"] == many["bounds"]


def test_sampled_mean_within_interval_of_exact_1M():
    rng = np.random.default_rng(7)
    n = 1_000_000
    u = rng.random((n, 2))
    a = np.c_[u, 0.05 * np.sin(8 * u[:, 0]) + 0.001 * rng.random(n)]
    b = a[np.sort(rng.choice(n, n // 2, replace=False))]
    exact = point_errors(a, b)
    sampled = point_errors(a, b, PointLevel(sample=20_000, seed=3))
    assert sampled["mode"] == "sampled"
    assert sampled["forward"]["count"] == 20_000
    lo, hi = sampled["forward"]["ci"]["mean"]
    assert lo <= exact["forward"]["mean"] <= hi
    lo, hi = sampled["forward"]["ci"]["rms"]
    assert lo <= exact["forward"]["rms"] <= hi
    assert sampled["forward"]["max"] <= exact["forward"]["max"]
    assert sampled["forward"]["max_is_lower_bound"] is True
    # a subset: backward is exactly zero, sampled or not
    assert exact["backward"]["max"] == 0 and sampled["backward"]["max"] == 0
    assert exact["subset"] is True


def test_sampled_is_seeded():
    rng = np.random.default_rng(8)
    a = rng.random((5000, 3))
    b = a[::4] + 1e-3
    r1 = point_errors(a, b, PointLevel(sample=500, seed=11))
    r2 = point_errors(a, b, PointLevel(sample=500, seed=11, chunk_size=333))
    assert r1["forward"]["max"] == r2["forward"]["max"]
    assert_allclose(r1["forward"]["mean"], r2["forward"]["mean"], rtol=1e-12)
    assert_allclose(r1["backward"]["mean"], r2["backward"]["mean"], rtol=1e-12)


def test_error_points_match_forward_distances():
    rng = np.random.default_rng(9)
    a = rng.random((4000, 3))
    b = a[::5]
    got = []
    point_errors(a, b, PointLevel(chunk_size=700, error_points=1000), on_error_points=lambda x, e: got.append((x, e)))
    xyz = np.concatenate([x for x, _ in got])
    err = np.concatenate([e for _, e in got])
    assert len(xyz) == 1000
    f, _ = _brute(xyz, b)
    assert_allclose(err, f, rtol=1e-6)


def test_empty_simplified_is_a_clear_error():
    with pytest.raises(EmptyInputError, match="simplified cloud is empty"):
        point_errors(np.random.default_rng(0).random((10, 3)), np.zeros((0, 3)))


def test_not_a_subset_when_claimed():
    rng = np.random.default_rng(1)
    a = rng.random((1000, 3))
    b = a[::10].copy()
    b[3] += 0.01
    with pytest.raises(NotASubsetError, match=r"1 of 100 simplified points are not points of the original"):
        point_errors(a, b, PointLevel(subset=True))
    assert point_errors(a, a[::10], PointLevel(subset=True))["subset"] is True


def test_dask_localcluster_equals_local():
    distributed = pytest.importorskip("distributed")
    rng = np.random.default_rng(12)
    a = rng.random((30_000, 3))
    b = np.concatenate([a[::2], rng.random((50, 3))])
    local = point_errors(a, b, PointLevel(chunk_size=4000))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster, \
            distributed.Client(cluster) as client:
        remote = point_errors(a, b, PointLevel(chunk_size=4000), client=client)
    for name in ("forward", "backward"):
        assert remote[name]["count"] == local[name]["count"]
        assert remote[name]["max"] == local[name]["max"]
        assert_allclose(remote[name]["mean"], local[name]["mean"], rtol=1e-12)
        assert_allclose(remote[name]["d2_mse"], local[name]["d2_mse"], rtol=1e-12)  # D2 too
    assert remote["histogram"] == local["histogram"]


def test_store_and_file_sources_equal_array(tmp_path):
    from conftest import shared_file

    from cloudsieve.store import ingest
    from cloudsieve.io import read_cloud

    src = shared_file("autzen_trim.laz")
    xyz, _ = read_cloud(src)
    b = xyz[::7]
    store = ingest(src, tmp_path / "s.zarr", chunk_size=30_000)
    ref = point_errors(xyz, b)
    for original in (src, str(tmp_path / "s.zarr"), store):
        r = point_errors(original, b, PointLevel(chunk_size=30_000))
        assert r["original_count"] == len(xyz) == 110_000
        assert r["forward"]["max"] == ref["forward"]["max"]
        assert_allclose(r["forward"]["mean"], ref["forward"]["mean"], rtol=1e-12)
        assert r["backward"]["max"] == 0.0


def test_distance_bound_keeps_results_exact():
    """Later chunks query with an upper bound learnt from earlier ones; far points are re-queried."""
    rng = np.random.default_rng(13)
    a = rng.random((12_000, 3))
    a[-50:] += 5.0  # far outliers in the last chunk: beyond any learnt bound
    b = a[: len(a) - 50 : 3]
    r = point_errors(a, b, PointLevel(chunk_size=4000))
    f = cKDTree_query(b, a)
    assert r["forward"]["max"] == pytest.approx(f.max(), rel=1e-12)
    assert_allclose(r["forward"]["mean"], f.mean(), rtol=1e-12)


def cKDTree_query(b, a):
    from scipy.spatial import cKDTree

    return cKDTree(b).query(a)[0]
