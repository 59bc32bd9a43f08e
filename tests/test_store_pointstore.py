"""The point store API: open/create/finish, is_store, chunks, derived arrays, delete."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.errors import DestinationExistsError, InvalidParameterError, StoreNotFoundError
from cloudsieve.io import open_reader
from cloudsieve.store import (
    DEFAULT_CHUNK_SIZE,
    Chunk,
    PointStore,
    delete_store,
    export,
    ingest,
    is_store,
)


def test_store_file_url_and_api(tmp_path):
    url = "file://" + str(tmp_path / "s.zarr")
    store = ingest(shared_file("simple.laz"), url, chunk_size=100)
    assert store.path == url
    same = PointStore.open(tmp_path / "s.zarr")
    assert same.count == store.count == 1065
    assert same.chunk_size == 100
    assert same.group["xyz"].chunks == (100, 3)
    assert same.group["intensity"].chunks == (100,)
    assert same.source_format == "laz"
    meta = same.attrs["cloudsieve"]
    assert meta["version"] == 1 and meta["complete"] is True and meta["count"] == 1065
    las = laspy.read(shared_file("simple.laz"))
    np.testing.assert_array_equal(same.read("intensity", 10, 20), las.intensity[10:20])
    np.testing.assert_array_equal(store.read("xyz")[:, 2], las.z)
    starts = [s for s, _ in store.chunks(["xyz", "classification"], chunk_size=250)]
    assert starts == [0, 250, 500, 750, 1000]
    parts = [c["classification"] for _, c in store.chunks(["classification"], chunk_size=250)]
    np.testing.assert_array_equal(np.concatenate(parts), las.classification)
    # derived arrays, from a read-only handle; input arrays are protected
    labels = store.create_array("partition/labels", shape=(1065,), dtype=np.int32)
    labels[:] = np.arange(1065) % 7
    np.testing.assert_array_equal(PointStore.open(url).read("partition/labels")[:8], [0, 1, 2, 3, 4, 5, 6, 0])
    with pytest.raises(Exception, match="'intensity' is an input array"):
        store.create_array("intensity", shape=(1065,), dtype=np.uint16)
    export(url, tmp_path / "o.laz")
    assert laspy.read(tmp_path / "o.laz").header.point_count == 1065
    # export with a mask from the URL store
    keep = store.create_array("simplify/keep", shape=(1065,), dtype=bool)
    keep[:] = np.arange(1065) < 10
    export(url, tmp_path / "k.laz", mask="simplify/keep")
    assert laspy.read(tmp_path / "k.laz").header.point_count == 10




def test_is_store_only_for_complete_stores(tmp_path):
    store = ingest(shared_file("simple.las"), tmp_path / "s.zarr", chunk_size=300)
    assert is_store(tmp_path / "s.zarr") and is_store(str(tmp_path / "s.zarr")) and is_store(store.path)
    assert is_store("file://" + str(tmp_path / "s.zarr"))
    assert not is_store(tmp_path / "none.zarr")
    assert not is_store(shared_file("simple.las"))
    (tmp_path / "folder").mkdir()
    assert not is_store(tmp_path / "folder")
    # created but not finished: not a store until finish()
    new = PointStore.create(tmp_path / "new.zarr", dtypes={"xyz": (np.float64, (3,))}, chunk_size=4, count=5)
    assert not new.complete and not is_store(tmp_path / "new.zarr")
    with pytest.raises(StoreNotFoundError, match="is not a complete cloudsieve point store"):
        PointStore.open(tmp_path / "new.zarr")


def test_create_finish_and_chunks(tmp_path):
    path = tmp_path / "c.zarr"
    dtypes = {"xyz": (np.float64, (3,)), "intensity": (np.uint16, ())}
    new = PointStore.create(path, dtypes=dtypes, chunk_size=4, count=10)
    xyz = np.arange(30, dtype=np.float64).reshape(10, 3)
    new.group["xyz"][:] = xyz
    new.group["intensity"][:] = np.arange(10, dtype=np.uint16)
    new.finish({"count": 10, "bounds": [xyz.min(0).tolist(), xyz.max(0).tolist()], "format": "xyz",
                "header": {}, "dimensions": list(dtypes), "chunk_size": 4})
    assert new.complete and new.count == 10
    store = PointStore.open(path)
    assert store.attrs["cloudsieve"]["version"] == 1 and store.attrs["cloudsieve"]["complete"] is True
    assert store.dtypes == {"xyz": (np.dtype(np.float64), (3,)), "intensity": (np.dtype(np.uint16), ())}
    chunks = list(store.chunks())
    assert all(isinstance(c, Chunk) for c in chunks)
    assert [c.start for c in chunks] == [0, 4, 8] and [c.stop for c in chunks] == [4, 8, 10]
    np.testing.assert_array_equal(np.concatenate([c.xyz for c in chunks]), xyz)
    np.testing.assert_array_equal(np.concatenate([a["intensity"] for _, a in chunks]), np.arange(10))
    with pytest.raises(DestinationExistsError, match=f"{path} exists; pass overwrite=True"):
        PointStore.create(path, dtypes=dtypes)
    PointStore.create(path, dtypes=dtypes, overwrite=True)
    assert not is_store(path)


def test_readers_and_stores_yield_the_same_chunks(tmp_path):
    src = shared_file("simple.laz")
    store = ingest(src, tmp_path / "s.zarr", chunk_size=300)
    with open_reader(src, chunk_size=300) as reader:
        from_file = list(reader.chunks())
    from_store = list(store.chunks())
    assert [c.start for c in from_file] == [c.start for c in from_store] == [0, 300, 600, 900]
    for a, b in zip(from_file, from_store):
        assert list(a.arrays) == list(b.arrays)
        for name in a.arrays:
            np.testing.assert_array_equal(a.arrays[name], b.arrays[name])
    assert DEFAULT_CHUNK_SIZE == 1_000_000 and reader.chunk_size == 300


def test_derived_arrays_require_delete(tmp_path):
    store = ingest(shared_file("simple.las"), tmp_path / "s.zarr", chunk_size=300)
    a = store.create_array("stage/data", data=np.arange(5, dtype=np.int64), chunks=(5,))
    assert a.shape == (5,) and a.dtype == np.int64
    np.testing.assert_array_equal(store.read("stage/data"), np.arange(5))
    s = store.create_array("stage/sharded", shape=(4, 8, 3), dtype="float64", chunks=(1, 4, 3), shards=(1, 8, 3))
    assert s.shards == (1, 8, 3)
    r = store.require_array("stage/flags", shape=(1065,), dtype=bool, fill_value=False)
    r[:3] = True
    assert store.require_array("stage/flags", shape=(1065,), dtype=bool, fill_value=False)[:3].all()  # kept
    assert not store.require_array("stage/flags", shape=(7,), dtype=bool, fill_value=False)[:].any()  # replaced
    assert store.delete_array("stage/data") and "stage/data" not in store
    assert not store.delete_array("stage/data")
    assert store.delete_array("stage") and "stage/flags" not in store
    with pytest.raises(InvalidParameterError, match="'intensity' is an input array"):
        store.delete_array("intensity")
    with pytest.raises(InvalidParameterError, match="array 'stage/x' needs data, or a shape and a dtype"):
        store.create_array("stage/x", shape=(3,))
    assert "intensity" in store and is_store(store.path)


def test_delete_store(tmp_path):
    ingest(shared_file("simple.las"), tmp_path / "s.zarr")
    delete_store(tmp_path / "s.zarr")
    assert not (tmp_path / "s.zarr").exists()
    delete_store(tmp_path / "s.zarr")  # missing: nothing to do


def test_export_selects_chunk_by_chunk_and_stops_its_reader_on_error(tmp_path):
    import threading

    src = shared_file("simple.laz")
    store = ingest(src, tmp_path / "s.zarr", chunk_size=100)
    keep = np.random.default_rng(0).random(1065) < 0.4
    store.create_array("simplify/keep", shape=(1065,), dtype=bool)[:] = keep
    export(store, tmp_path / "k.laz", mask="simplify/keep", chunk_size=250)
    las, out = laspy.read(src), laspy.read(tmp_path / "k.laz")
    assert out.header.point_count == keep.sum()
    for name in ("X", "Y", "Z", "intensity", "gps_time", "classification", "return_number"):
        np.testing.assert_array_equal(out[name], las[name][keep])  # the boolean index is the oracle
    # a mask chunk that cannot be decoded, read by the prefetch thread: the error reaches the caller, no
    # file is left under the destination's name, and the reading thread has stopped
    (tmp_path / "s.zarr" / "simplify" / "keep" / "c" / "5").write_bytes(b"not a blosc frame")
    with pytest.raises(RuntimeError, match="error during blosc decompression"):
        export(store, tmp_path / "bad.laz", mask="simplify/keep", chunk_size=100)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.laz", "s.zarr"]
    assert not [t for t in threading.enumerate() if t.name == "cloudsieve-reader"]


def test_a_store_left_before_its_first_array_is_cloudsieve_s_not_foreign(tmp_path):
    """A crash between the group and its arrays leaves a store a rerun may replace: marked incomplete from the
    start (paths.store_foreign: None), and still no store to open."""
    from cloudsieve.paths import store_foreign

    path = tmp_path / "s.zarr"
    PointStore.create(path, dtypes={"xyz": (np.dtype("f8"), (3,))})
    assert store_foreign(path) is None
    assert not is_store(path)
