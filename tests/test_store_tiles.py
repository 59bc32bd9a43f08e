"""Out-of-core grouping by key (store/buckets.py) and tiled export (store/tiles.py) on a real scan.

The grouping is checked against an in-memory groupby; the tiles against the
input's raw LAS records, on dask's sync scheduler and a real LocalCluster.
"""

from __future__ import annotations

import json
import os
import pickle
from functools import partial

import laspy
import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.engine.runner import Runner
from cloudsieve.errors import (
    ArrayNotFoundError,
    DestinationExistsError,
    InputFormatError,
    InvalidParameterError,
    SameSourceDestinationError,
)
from cloudsieve.io.vpc import read_vpc
from cloudsieve.store import PointStore, ingest
from cloudsieve.store.buckets import Buckets, bucket, read_runs
from cloudsieve.store.tiles import export_tiles, tile_index, tile_keys


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
    # read from its runs alone (as a task does), reopened and unpickled, it reads the same
    np.testing.assert_array_equal(read_runs(store.path, "all", runs)["intensity"], groups[big]["intensity"])
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
    assert "export/x" not in store.group  # a failed grouping leaves no scratch
    with pytest.raises(InvalidParameterError, match=r"got float64 \(16000,\)"):
        bucket(store, float_keys, "x")
    with pytest.raises(InvalidParameterError, match=r"bucket name must be a non-empty name without '/', got 'a/b'"):
        bucket(store, float_keys, "a/b")


# ------------------------------------------------------------------ tiles
def raw_records(path) -> np.ndarray:
    """The raw point records of a LAS/LAZ file, one bytes row per point."""
    arr = laspy.read(str(path)).points.array
    return np.ascontiguousarray(arr).view(np.dtype((np.void, arr.dtype.itemsize))).ravel()


def folder_bytes(folder) -> dict[str, bytes]:
    return {name: (folder / name).read_bytes() for name in sorted(os.listdir(folder))}


def test_tile_keys_grid():
    s = 0.1
    x = np.array([0.0, 0.3, -0.3, 0.29999999999999999, -1e-300, 2.5, 1e6 + 0.05, -7.0])
    xyz = np.c_[x, x[::-1], np.zeros(len(x))]
    ix, iy = tile_index(tile_keys(xyz, s))
    assert np.all((ix * s <= xyz[:, 0]) & (xyz[:, 0] < (ix + 1) * s))
    assert np.all((iy * s <= xyz[:, 1]) & (xyz[:, 1] < (iy + 1) * s))
    assert ix[0] == 0 and ix[4] == -1 and ix[7] == -70
    rng = np.random.default_rng(3)
    xyz = rng.uniform(-1e5, 1e5, (10_000, 3))
    for size in (0.37, 1.0, 250.0):
        k = tile_keys(xyz, size)
        ix, iy = tile_index(k)
        assert np.all((ix * size <= xyz[:, 0]) & (xyz[:, 0] < (ix + 1) * size))
        assert np.all((iy * size <= xyz[:, 1]) & (xyz[:, 1] < (iy + 1) * size))
        order = np.lexsort((iy, ix))  # keys sort as (ix, iy)
        assert np.all(np.diff(k[order]) >= 0)
    with pytest.raises(InvalidParameterError, match=r"tile_size 1e-06 is too small for coordinates up to 1e\+06"):
        tile_keys(np.array([[1e6, 0.0, 0.0]]), 1e-6)


def test_export_tiles_round_trip(autzen, tmp_path):
    store, keep = autzen
    size = 250.0
    out = tmp_path / "tiles"
    summary = export_tiles(store, out, tile_size=size, mask="simplify/keep")
    src = laspy.read(str(shared_file("autzen_trim.laz")))
    records = raw_records(shared_file("autzen_trim.laz"))[keep]
    keys = tile_keys(np.c_[src.x, src.y, src.z][keep], size)
    uniq = np.unique(keys)
    ix, iy = tile_index(uniq)
    names = [f"tiles_{i}_{j}.laz" for i, j in zip(ix, iy)]
    assert summary == {"tiles": len(uniq), "points": int(keep.sum()), "files": [str(out / n) for n in names],
                       "vpc": str(out / "index.vpc"), "tile_size": size}
    assert sorted(os.listdir(out)) == sorted(names + ["index.vpc"])  # nothing else: no temporary file
    assert not any(n.startswith(".tiles") for n in os.listdir(tmp_path))
    assert "export/tiles" not in PointStore.open(store.path).group  # scratch deleted
    wkt_vlr = [(v.user_id, v.record_id, v.record_data_bytes()) for v in src.header.vlrs
               if type(v).__name__ != "LasZipVlr"]
    for key, i, j, name in zip(uniq, ix, iy, names):
        tile = laspy.read(str(out / name))
        # exactly the kept records of that square, in input order
        np.testing.assert_array_equal(raw_records(out / name), records[keys == key])
        assert np.all((i * size <= tile.x) & (tile.x < (i + 1) * size))
        assert np.all((j * size <= tile.y) & (tile.y < (j + 1) * size))
        h = tile.header
        assert h.point_format.id == 3 and str(h.version) == "1.2"
        np.testing.assert_array_equal(h.scales, src.header.scales)
        np.testing.assert_array_equal(h.offsets, src.header.offsets)
        assert h.creation_date == src.header.creation_date
        assert [(v.user_id, v.record_id, v.record_data_bytes()) for v in h.vlrs
                if type(v).__name__ != "LasZipVlr"] == wkt_vlr  # every VLR, the WKT CRS among them
    # the index: counts and bboxes as the files' headers say
    assert read_vpc(out / "index.vpc") == [str(out / n) for n in names]
    doc = json.loads((out / "index.vpc").read_text())
    for name, f in zip(names, doc["features"]):
        h = laspy.open(str(out / name)).header
        assert f["id"] == name[:-4] and f["assets"]["data"]["href"] == f"./{name}"
        assert f["properties"]["pc:count"] == h.point_count
        assert f["properties"]["proj:bbox"] == [*h.mins, *h.maxs]
        assert f["properties"]["proj:wkt2"].startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"')
    assert sum(f["properties"]["pc:count"] for f in doc["features"]) == keep.sum()


def test_export_tiles_same_bytes_on_any_scheduler(autzen, tmp_path):
    from distributed import Client, LocalCluster

    from cloudsieve.engine.runner import NO_HTTP_PORT

    store, _ = autzen
    for x in "abc":
        (tmp_path / x).mkdir()
    export_tiles(store, tmp_path / "a" / "t", tile_size=300.0, mask="simplify/keep")
    sync = Runner("sync")
    export_tiles(store.path, tmp_path / "b" / "t", tile_size=300.0, mask="simplify/keep", run=sync)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster, Client(cluster) as client:
        run = Runner(client=client)
        export_tiles(store.path, tmp_path / "c" / "t", tile_size=300.0, mask="simplify/keep", run=run)
        pids = set(client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids
    a, b, c = (folder_bytes(tmp_path / x / "t") for x in "abc")
    assert len(a) > 8 and a == b == c


def test_export_tiles_atomic_and_refusals(autzen, tmp_path):
    store, _ = autzen
    out = tmp_path / "tiles"
    out.mkdir()
    (out / "tiles_0_0.laz").write_text("kept")  # an earlier export's tile: replaced only with overwrite
    with pytest.raises(DestinationExistsError, match=r"tiles exists \(a folder\); pass overwrite=True to replace it"):
        export_tiles(store, out, tile_size=400.0)
    with pytest.raises(InvalidParameterError, match=r"tile_size must be a finite number > 0, got -1.0"):
        export_tiles(store, out, tile_size=-1, overwrite=True)
    with pytest.raises(InvalidParameterError, match=r"tile_size 1e-05 is too small for .*: coordinates up to "
                                                    r"849498 give tile indices beyond 32 bits"):
        export_tiles(store, out, tile_size=1e-5, overwrite=True)
    with pytest.raises(SameSourceDestinationError, match=r"is or holds the source .*s.zarr: cloudsieve never overwrites its input"):
        export_tiles(store, tmp_path, tile_size=400.0, overwrite=True)
    # a header whose x offset leaves the east half of the points beyond LAS int32: those tiles' tasks fail
    meta = store.attrs["cloudsieve"]
    meta["header"]["offsets"][0] = 636600.0 - 0.01 * 2**31
    PointStore.open(store.path, "r+").group.attrs.update({"cloudsieve": meta})
    for overwrite, dst in ((True, out), (False, tmp_path / "new")):
        with pytest.raises(InputFormatError, match=r"x values .* do not fit LAS int32 with scale 0.01"):
            export_tiles(store.path, dst, tile_size=200.0, overwrite=overwrite)
    assert sorted(os.listdir(tmp_path)) == ["s.zarr", "tiles"]  # nothing new, no temporary folder
    assert sorted(os.listdir(out)) == ["tiles_0_0.laz"]  # the old folder untouched
    assert "export/tiles" not in PointStore.open(store.path).group
    # overwrite replaces the folder once the new tiles are complete
    meta["header"]["offsets"][0] = 636000.0
    PointStore.open(store.path, "r+").group.attrs.update({"cloudsieve": meta})
    summary = export_tiles(store.path, out, tile_size=400.0, overwrite=True)
    assert sorted(os.listdir(out)) == sorted([os.path.basename(f) for f in summary["files"]] + ["index.vpc"])
    assert summary["points"] == store.count


def test_export_tiles_of_a_ply_scan_and_of_no_point(tmp_path):
    from cloudsieve.errors import EmptyInputError
    from cloudsieve.io import read_cloud

    store = ingest(shared_file("bun_zipper.ply"), tmp_path / "bun.zarr", chunk_size=10_000)
    size = 0.05
    summary = export_tiles(store, tmp_path / "bun", tile_size=size)
    xyz, attrs = read_cloud(shared_file("bun_zipper.ply"))
    keys = tile_keys(xyz, size)
    uniq = np.unique(keys)
    assert summary["tiles"] == len(uniq) > 4 and summary["points"] == len(xyz)
    scales = set()
    for key, path in zip(uniq, summary["files"]):
        tile = laspy.read(path)
        sel = keys == key
        # a fresh header (scales chosen from the store's bounds, the same for every tile): coordinates to its scale
        np.testing.assert_allclose(np.c_[tile.x, tile.y, tile.z], xyz[sel], rtol=0, atol=tile.header.scales.max())
        np.testing.assert_array_equal(tile["confidence"], attrs["confidence"][sel])
        scales.add(tuple(tile.header.scales) + tuple(tile.header.offsets))
    assert len(scales) == 1
    doc = json.loads((tmp_path / "bun" / "index.vpc").read_text())
    assert [f["properties"]["proj:wkt2"] for f in doc["features"]] == [""] * len(uniq)  # no CRS
    # no point kept: an empty tile set and an empty index
    store.create_array("simplify/keep", data=np.zeros(store.count, dtype=bool))
    summary = export_tiles(store, tmp_path / "none", tile_size=size, mask="simplify/keep")
    assert summary["tiles"] == summary["points"] == 0 and summary["files"] == []
    assert os.listdir(tmp_path / "none") == ["index.vpc"]
    with pytest.raises(EmptyInputError, match=r"the VPC lists no files"):
        read_vpc(tmp_path / "none" / "index.vpc")


@pytest.mark.parametrize("name, size", [("extrabytes.las", 1000.0), ("1_4_w_evlr.laz", 100.0),
                                        ("append-bug.laz", 300.0), ("simple.copc.laz", 1000.0)])
def test_export_tiles_keeps_every_record_and_record_kind(tmp_path, name, size):
    """Extra bytes, LAS 1.4 EVLRs, point format 8: each tile holds exactly the input records of its square."""
    src = shared_file(name)
    store = ingest(src, tmp_path / "s.zarr", chunk_size=3_000)
    summary = export_tiles(store, tmp_path / "t", tile_size=size)
    las = laspy.read(str(src))
    keys = tile_keys(np.c_[las.x, las.y, las.z], size)
    records = raw_records(src)
    assert summary["tiles"] == len(np.unique(keys)) > 1
    for key, path in zip(np.unique(keys), summary["files"]):
        np.testing.assert_array_equal(raw_records(path), records[keys == key])
        tile = laspy.read(path)
        # every VLR and EVLR but COPC's own (its octree layout: dropped, see io/las_header.py)
        assert [(v.user_id, v.record_id) for v in tile.header.vlrs] == [
            (v.user_id, v.record_id) for v in las.header.vlrs if v.user_id != "copc"]
        assert [(v.user_id, v.record_id, v.record_data_bytes()) for v in tile.evlrs or []] == [
            (v.user_id, v.record_id, v.record_data_bytes()) for v in las.evlrs or [] if v.user_id != "copc"]
