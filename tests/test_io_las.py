"""LAS/LAZ/COPC: every real file goes file -> store -> LAS/LAZ and back unchanged."""

from __future__ import annotations

import json
import logging

import laspy
import numpy as np
import pytest
from conftest import LAS_FILES, shared_file

from cloudsieve.store import export, ingest
from cloudsieve.io import open_reader
from cloudsieve.store import PointStore

# VLRs that describe the compression or the COPC octree of one file, not the cloud
NOT_CARRIED = {"laszip encoded", "copc"}


def _raw(las: laspy.LasData, name: str) -> np.ndarray:
    if name in ("X", "Y", "Z"):
        return np.asarray(las.points.array[name])
    values = las[name]
    if isinstance(values, laspy.point.dims.ScaledArrayView):
        values = values.array
    return np.asarray(values)


def _vlrs(vlrs) -> list[tuple[str, int, str, bytes]]:
    return [(v.user_id, v.record_id, v.description, v.record_data_bytes()) for v in vlrs if v.user_id not in NOT_CARRIED]


def assert_same_las(src, out) -> None:
    a, b = laspy.read(src), laspy.read(out)
    assert b.header.point_count == a.header.point_count == len(b.points)
    assert b.header.version == a.header.version
    assert b.point_format == a.point_format
    assert list(b.point_format.dimension_names) == list(a.point_format.dimension_names)
    for name in a.point_format.dimension_names:
        np.testing.assert_array_equal(_raw(b, name), _raw(a, name), err_msg=f"{src.name}: dimension {name}")
    np.testing.assert_array_equal(b.header.scales, a.header.scales)
    np.testing.assert_array_equal(b.header.offsets, a.header.offsets)
    np.testing.assert_allclose(b.header.mins, a.header.mins, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.header.maxs, a.header.maxs, rtol=0, atol=1e-9)
    assert _vlrs(b.header.vlrs) == _vlrs(a.header.vlrs)
    assert _vlrs(b.evlrs or []) == _vlrs(a.evlrs or [])
    assert b.header.system_identifier == a.header.system_identifier
    assert b.header.generating_software == a.header.generating_software
    assert b.header.creation_date == a.header.creation_date
    assert b.header.global_encoding.value == a.header.global_encoding.value
    assert b.header.uuid == a.header.uuid
    if a.header.version.minor >= 1:
        np.testing.assert_array_equal(b.header.number_of_points_by_return, a.header.number_of_points_by_return)
    crs_a = [v for v in a.header.vlrs if type(v).__name__ in ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr")]
    crs_b = [v for v in b.header.vlrs if type(v).__name__ in ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr")]
    assert _vlrs(crs_b) == _vlrs(crs_a)


@pytest.mark.parametrize("name", LAS_FILES)
def test_las_round_trip_through_store(name, tmp_path):
    src = shared_file(name)
    chunk = 7_919 if name.startswith(("autzen", "Megaplot", "append")) else 97  # odd sizes: chunk borders move
    store = ingest(src, tmp_path / "s.zarr", chunk_size=chunk)
    with laspy.open(src) as f:
        assert store.count == f.header.point_count
        np.testing.assert_allclose(store.bounds, [f.header.mins, f.header.maxs], rtol=0, atol=1e-6)
    assert store.dimensions[0] == "xyz"
    json.dumps(store.header)  # the header is plain JSON
    ext = ".laz" if name.endswith(".laz") else ".las"
    out = tmp_path / f"out{ext}"
    export(store, out, chunk_size=chunk * 3 + 1)
    assert_same_las(src, out)


@pytest.mark.parametrize("name", ["simple.las", "extrabytes.las", "1_4_w_evlr.laz", "vegetation_1_3.las"])
def test_las_laz_cross_round_trip(name, tmp_path):
    """LAS in, LAZ out (and LAZ in, LAS out): same points and header bar the compression."""
    src = shared_file(name)
    store = ingest(src, tmp_path / "s.zarr", chunk_size=333)
    out = tmp_path / ("out.las" if name.endswith(".laz") else "out.laz")
    export(store, out, chunk_size=250)
    assert_same_las(src, out)
    with laspy.open(out) as f:
        assert f.header.are_points_compressed == (out.suffix == ".laz")


def test_copc_records_dropped_with_log(tmp_path, caplog):
    src = shared_file("simple.copc.laz")
    store = ingest(src, tmp_path / "s.zarr", chunk_size=400)
    assert store.source_format == "copc"
    assert [v["user_id"] for v in store.header["vlrs"]].count("copc") == 1
    assert [v["user_id"] for v in store.header["evlrs"]] == ["copc"]
    with caplog.at_level(logging.INFO, logger="cloudsieve.io.las_header"):
        export(store, tmp_path / "out.laz")
    messages = [r.getMessage() for r in caplog.records]
    assert any("dropping COPC record (user_id 'copc', record_id 1)" in m for m in messages)
    assert any("dropping COPC record (user_id 'copc', record_id 1000)" in m for m in messages)
    assert any("not valid in a re-ordered or plain LAS/LAZ file" in m for m in messages)
    out = laspy.read(tmp_path / "out.laz")
    assert not [v for v in out.header.vlrs if v.user_id == "copc"]
    assert not [v for v in (out.evlrs or []) if v.user_id == "copc"]
    assert any(type(v).__name__ == "WktCoordinateSystemVlr" for v in out.header.vlrs)  # the CRS stays


def test_copc_to_copc(tmp_path):
    store = ingest(shared_file("simple.copc.laz"), tmp_path / "s.zarr")
    export(store, tmp_path / "out.copc.laz")  # an octree built afresh (cloudsieve.store.copc)
    with laspy.CopcReader.open(str(tmp_path / "out.copc.laz")) as reader:
        assert len(reader.query()) == store.count == 1065


def test_reader_chunks_and_dtypes():
    src = shared_file("extrabytes.las")
    with open_reader(src, chunk_size=100) as reader:
        assert reader.format == "las"
        assert reader.count == 1065
        assert reader.dtypes["xyz"] == (np.dtype(np.float64), (3,))
        assert reader.dtypes["Colors"] == (np.dtype(np.uint16), (3,))
        assert reader.dtypes["Reserved"] == (np.dtype(np.uint8), (7,))
        assert reader.dtypes["classification"][0] == np.uint8
        sizes = []
        for start, chunk in reader.chunks():
            assert start == sum(sizes)
            sizes.append(len(chunk["xyz"]))
            for name, (dtype, shape) in reader.dtypes.items():
                assert chunk[name].dtype == dtype and chunk[name].shape[1:] == shape, name
        assert sizes == [100] * 10 + [65]
    las = laspy.read(src)
    np.testing.assert_array_equal(chunk["xyz"][-1], [las.x[-1], las.y[-1], las.z[-1]])


def test_crs_in_header():
    with open_reader(shared_file("append-bug.laz")) as reader:
        assert reader.header["crs"]["epsg"] == 2154
        assert reader.header["crs"]["name"] == "RGF93 / Lambert-93"
    with open_reader(shared_file("simple.las")) as reader:
        assert reader.header["crs"] is None


def test_export_mask_updates_counts_and_bounds(tmp_path):
    src = shared_file("autzen_trim.laz")
    store = ingest(src, tmp_path / "s.zarr", chunk_size=25_000)
    xyz = store.read("xyz")
    keep = xyz[:, 2] > 450.0
    arr = store.create_array("simplify/keep", shape=(store.count,), dtype=bool)
    arr[:] = keep
    out = tmp_path / "kept.laz"
    export(store, out, mask="simplify/keep", chunk_size=10_000)
    a, b = laspy.read(src), laspy.read(out)
    assert b.header.point_count == int(keep.sum())
    np.testing.assert_array_equal(b.points.array, a.points.array[keep])  # input order, every byte
    np.testing.assert_allclose(b.header.mins, xyz[keep].min(axis=0), atol=1e-9)
    np.testing.assert_allclose(b.header.maxs, xyz[keep].max(axis=0), atol=1e-9)
    counts = np.bincount(np.asarray(a.return_number)[keep], minlength=6)[1:6]
    np.testing.assert_array_equal(b.header.number_of_points_by_return[:5], counts)
    # a numpy mask and a zarr mask give the same file bytes
    export(store, tmp_path / "np.laz", mask=keep)
    export(store, tmp_path / "zarr.laz", mask=store.array("simplify/keep"))
    assert (tmp_path / "np.laz").read_bytes() == out.read_bytes() == (tmp_path / "zarr.laz").read_bytes()


def test_store_reopened_from_disk(tmp_path):
    store = ingest(shared_file("simple.laz"), tmp_path / "s.zarr", chunk_size=200)
    again = PointStore.open(tmp_path / "s.zarr")
    assert again.count == store.count == 1065
    assert again.header == store.header
    assert again.group["xyz"].chunks == (200, 3)
