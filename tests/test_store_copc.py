"""COPC output (store/copc.py) on real scans: read back by laspy's CopcReader and copc-lib, against the sources."""

from __future__ import annotations

import os
import struct

import laspy
import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.engine.runner import Runner
from cloudsieve.errors import (
    ArrayNotFoundError,
    DestinationExistsError,
    InvalidParameterError,
    SameSourceDestinationError,
)
from cloudsieve.store import PointStore, ingest
from cloudsieve.store.copc import export_copc
from cloudsieve.store.octree import GRID_BITS, KEY_DEPTH, assign_levels, group_nodes, point_keys, root_cube

SMALL = {"task_points": 12_000, "leaf_points": 3_000}  # many subtree tasks and a 5-level tree on 110 000 points


@pytest.fixture(scope="module")
def autzen_store(tmp_path_factory):
    """autzen_trim.laz (110 000 points, PF3) in a store of 16 000-point chunks."""
    return ingest(shared_file("autzen_trim.laz"), tmp_path_factory.mktemp("s") / "s.zarr", chunk_size=16_000)


def expected_records(src: laspy.LasData, point_format: laspy.PointFormat) -> dict[str, np.ndarray]:
    """The source's records in *point_format* (PDAL's mapping: scan_angle = round(rank / 0.006), new fields 0)."""
    names = set(src.point_format.dimension_names)
    out = {}
    for name in point_format.dimension_names:
        if name in names:
            out[name] = np.asarray(src[name])
        elif name == "scan_angle":
            out[name] = np.round(np.asarray(src["scan_angle_rank"], dtype=np.float32) / np.float32(0.006))
        else:
            out[name] = np.zeros(len(src.points), dtype=np.int64)
    return out


def columns(records: dict[str, np.ndarray]) -> list[np.ndarray]:
    cols = []
    for name in sorted(records):
        v = np.asarray(records[name])
        cols += [v[:, i] for i in range(v.shape[1])] if v.ndim == 2 else [v]
    return cols


def assert_same_records(got: laspy.ScaleAwarePointRecord, want: dict[str, np.ndarray]) -> None:
    """Every wanted record exactly once (as multisets), every field compared raw."""
    have = {n: np.asarray(got[n]) for n in want}
    a, b = columns(have), columns(want)
    assert len(a[0]) == len(b[0])
    oa, ob = np.lexsort(a), np.lexsort(b)
    for name, x, y in zip(sorted(want), a, b):
        np.testing.assert_array_equal(x[oa], y[ob].astype(x.dtype), err_msg=name)


def leftover_buckets(store) -> list[str]:
    """Names of the buckets left in *store* (under export/)."""
    group = PointStore.open(store.path).group
    return sorted(group["export"].keys()) if "export" in group else []


def hierarchy(path: str) -> tuple[np.ndarray, dict]:
    """The hierarchy entries (d, x, y, z, offset, nbytes, count) of a COPC file, and its info VLR."""
    with open(path, "rb") as f:
        f.seek(375 + 54)
        info = struct.unpack("<5d2Q2d", f.read(72))
        f.seek(info[5])
        data = f.read(info[6])
    dtype = [("d", "<i4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("offset", "<u8"), ("nbytes", "<i4"),
             ("count", "<i4")]
    keys = ("cx", "cy", "cz", "halfsize", "spacing", "root_offset", "root_size", "gps_min", "gps_max")
    return np.frombuffer(data, dtype=dtype), dict(zip(keys, info))


def test_every_point_once_exact_records_and_hierarchy(autzen_store, tmp_path):
    dst = str(tmp_path / "a.copc.laz")
    out = export_copc(autzen_store, dst, **SMALL)
    assert out["points"] == 110_000 and out["tasks"] > 4 and out["depth"] >= 3
    src = laspy.read(shared_file("autzen_trim.laz"))
    with laspy.CopcReader.open(dst) as reader:
        h = reader.header
        assert (str(h.version), h.point_format.id, h.point_count) == ("1.4", 7, 110_000)
        np.testing.assert_array_equal(h.scales, src.header.scales)
        np.testing.assert_array_equal(h.offsets, src.header.offsets)
        ints = np.stack([src.X, src.Y, src.Z], axis=1)  # bounds: the extreme records' coordinates
        np.testing.assert_array_equal(h.mins, ints.min(axis=0) * src.header.scales + src.header.offsets)
        np.testing.assert_array_equal(h.maxs, ints.max(axis=0) * src.header.scales + src.header.offsets)
        points = reader.query()
    assert_same_records(points, expected_records(src, h.point_format))
    assert np.all(np.asarray(points["overlap"]) == 0) and np.all(np.asarray(points["scanner_channel"]) == 0)
    # read as a plain LAZ file too (through the chunk table)
    assert len(laspy.read(dst).points) == 110_000
    # the hierarchy: every node once, points summing to the cloud, every ancestor present, chunks back to back
    entries, info = hierarchy(dst)
    assert len(entries) == out["nodes"] and int(entries["count"].sum()) == 110_000 and np.all(entries["count"] > 0)
    keys = set(zip(*(entries[k].tolist() for k in "dxyz")))
    assert len(keys) == len(entries)
    for d, x, y, z in keys:
        if d:
            assert (d - 1, x // 2, y // 2, z // 2) in keys
    order = np.argsort(entries["offset"])
    ends = entries["offset"][order] + entries["nbytes"][order].astype(np.uint64)
    np.testing.assert_array_equal(entries["offset"][order][1:], ends[:-1])
    size = float(np.max(h.maxs - h.mins))
    assert info["halfsize"] == size / 2 and info["spacing"] == size / 128
    np.testing.assert_allclose([info["cx"], info["cy"], info["cz"]], h.mins + size / 2)
    assert (info["gps_min"], info["gps_max"]) == (src.gps_time.min(), src.gps_time.max())


def test_copclib_reads_and_validates(autzen_store, tmp_path):
    copclib = pytest.importorskip("copclib")
    dst = str(tmp_path / "a.copc.laz")
    export_copc(autzen_store, dst, **SMALL)
    reader = copclib.FileReader(dst)
    assert reader.ValidateSpatialBounds(False)  # every point inside its node's box
    assert len(reader.GetAllPoints()) == 110_000
    # (not reader.copc_config.wkt: copc-lib 2.6.3 reads the WKT 6 bytes late, in PDAL's own files too)


@pytest.mark.parametrize("box", [(636400.0, 849100.0, 400.0, 636900.0, 849300.0, 450.0),
                                 (636001.76, 848935.2, 0.0, 636500.0, 849497.9, 1000.0)])
def test_bounding_box_query_returns_exactly_the_points_inside(autzen_store, tmp_path, box):
    dst = str(tmp_path / "a.copc.laz")
    export_copc(autzen_store, dst, **SMALL)
    src = laspy.read(shared_file("autzen_trim.laz"))
    lo, hi = np.asarray(box[:3]), np.asarray(box[3:])
    scales, offsets = src.header.scales, src.header.offsets
    ilo, ihi = np.round((lo - offsets) / scales), np.round((hi - offsets) / scales)
    xyz = np.stack([src.X, src.Y, src.Z], axis=1)
    inside = np.all((xyz >= ilo) & (xyz <= ihi), axis=1)
    assert 100 < inside.sum() < 110_000
    with laspy.CopcReader.open(dst) as reader:
        got = reader.query(bounds=laspy.copc.Bounds(mins=lo, maxs=hi))
        want = expected_records(src, reader.header.point_format)
    assert_same_records(got, {n: v[inside] for n, v in want.items()})


def test_vlrs_crs_and_layout_kept(autzen_store, tmp_path):
    dst = str(tmp_path / "a.copc.laz")
    export_copc(autzen_store, dst, **SMALL)
    src = laspy.open(shared_file("autzen_trim.laz"))
    with open(dst, "rb") as f:
        raw = f.read()
    # the copc info VLR right after the 375-byte header, the LASzip VLR next
    assert raw[375 + 2:375 + 6] == b"copc" and struct.unpack_from("<H", raw, 375 + 18)[0] == 1
    assert raw[375 + 54 + 160 + 2:375 + 54 + 160 + 16].rstrip(b"\0") == b"laszip encoded"
    assert struct.unpack_from("<H", raw, 6)[0] & 0x10  # WKT bit
    with laspy.open(dst) as out:
        kept = [(v.user_id, v.record_id, v.record_data_bytes()) for v in out.header.vlrs
                if v.user_id not in ("copc", "laszip encoded")]
        h = out.header
    want = [(v.user_id, v.record_id, v.record_data_bytes()) for v in src.header.vlrs if v.user_id != "laszip encoded"]
    assert kept == want
    for field in ("system_identifier", "generating_software", "creation_date", "uuid", "file_source_id"):
        assert getattr(h, field) == getattr(src.header, field), field
    src.close()


def test_same_bytes_sync_processes_and_local_cluster(autzen_store, tmp_path):
    from distributed import Client, LocalCluster

    from cloudsieve.engine.runner import NO_HTTP_PORT

    a, b, c, d = (str(tmp_path / f"{n}.copc.laz") for n in "abcd")
    for path, run in ((a, Runner("sync")), (d, Runner("processes", workers=2))):
        try:
            export_copc(autzen_store, path, run=run, **SMALL)
        finally:
            run.close()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster, Client(cluster) as client:
        run = Runner(client=client)
        out = export_copc(autzen_store, b, run=run, **SMALL)
    assert out["tasks"] > 4
    # one subtree task for the whole cloud: the same file
    export_copc(autzen_store, c, leaf_points=SMALL["leaf_points"], task_points=1_000_000)
    data = [open(p, "rb").read() for p in (a, b, c, d)]
    assert data[0] == data[1] == data[2] == data[3]
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]  # no temporary left
    assert leftover_buckets(autzen_store) == []  # nor buckets in the store


def test_mask(autzen_store, tmp_path):
    keep = np.random.default_rng(3).random(autzen_store.count) < 0.3
    keep[np.argmin(autzen_store.read("xyz")[:, 0])] = False  # the kept points' bounds differ from the store's
    autzen_store.create_array("simplify/keep", data=keep, overwrite=True)
    dst = str(tmp_path / "m.copc.laz")
    placed = []
    out = export_copc(autzen_store, dst, mask="simplify/keep", progress=placed.append, **SMALL)
    assert out["points"] == int(keep.sum()) == sum(placed) and len(placed) == out["tasks"]
    src = laspy.read(shared_file("autzen_trim.laz"))
    with laspy.CopcReader.open(dst) as reader:
        got = reader.query()
        want = expected_records(src, reader.header.point_format)
        assert reader.header.mins[0] == src.x[keep].min()
    assert_same_records(got, {n: v[keep] for n, v in want.items()})
    copclib = pytest.importorskip("copclib")
    assert copclib.FileReader(dst).ValidateSpatialBounds(False)


def test_atomic_refusals_and_failures(autzen_store, tmp_path):
    dst = tmp_path / "a.copc.laz"
    dst.write_bytes(b"old")
    with pytest.raises(DestinationExistsError, match=r"a\.copc\.laz exists; pass overwrite=True to replace it"):
        export_copc(autzen_store, str(dst))
    assert dst.read_bytes() == b"old"
    with pytest.raises(SameSourceDestinationError, match=r"is the source .*: cloudsieve never overwrites its input"):
        export_copc(autzen_store, autzen_store.path, overwrite=True)
    with pytest.raises(ArrayNotFoundError, match=r"has no array 'simplify/none'"):
        export_copc(autzen_store, str(dst), mask="simplify/none", overwrite=True)
    autzen_store.create_array("simplify/rank", data=np.arange(autzen_store.count), overwrite=True)
    with pytest.raises(InvalidParameterError, match=r"mask 'simplify/rank' must be a boolean array of 110000 entries"):
        export_copc(autzen_store, str(dst), mask="simplify/rank", overwrite=True)
    with pytest.raises(InvalidParameterError, match=r"need 1 <= leaf_points <= task_points, got leaf_points=10"):
        export_copc(autzen_store, str(dst), leaf_points=10, task_points=5, overwrite=True)
    assert dst.read_bytes() == b"old" and sorted(os.listdir(tmp_path)) == ["a.copc.laz"]
    # a failure after the subtrees are written (a cluster losing its workers at the last stage) leaves nothing
    with pytest.raises(RuntimeError, match="workers lost"):
        export_copc(autzen_store, str(tmp_path / "b.copc.laz"), run=failing_at("export: copc file"), **SMALL)
    assert sorted(os.listdir(tmp_path)) == ["a.copc.laz"] and leftover_buckets(autzen_store) == []
    export_copc(autzen_store, str(dst), overwrite=True, **SMALL)
    assert dst.read_bytes()[:4] == b"LASF" and sorted(os.listdir(tmp_path)) == ["a.copc.laz"]


def failing_at(stage_name: str):
    """A runner running the tasks here, one after the other, that fails at stage *stage_name*."""
    def run(func, args, stage):
        if stage == stage_name:
            raise RuntimeError(f"workers lost at stage {stage}")
        return [func(*a) for a in args]
    return run


@pytest.mark.parametrize("name, fmt", [("Megaplot.laz", 6), ("extrabytes.las", 7), ("append-bug.laz", 8),
                                       ("1_4_w_evlr.laz", 6), ("simple.copc.laz", 7), ("vegetation_1_3.las", 6)])
def test_other_sources_exact(tmp_path, name, fmt):
    path = shared_file(name)
    store = ingest(path, tmp_path / "s.zarr", chunk_size=8_000)
    dst = str(tmp_path / "o.copc.laz")
    out = export_copc(store, dst, task_points=4_000, leaf_points=1_000)
    src = laspy.read(path)
    assert out["points"] == len(src.points)
    with laspy.CopcReader.open(dst) as reader:
        assert reader.header.point_format.id == fmt
        assert list(reader.header.point_format.extra_dimension_names) == list(src.point_format.extra_dimension_names)
        got = reader.query()
        assert_same_records(got, expected_records(src, reader.header.point_format))
    with laspy.open(dst) as f:  # EVLRs kept, the source's COPC records replaced by ours
        evlrs = [(v.user_id, v.record_id) for v in f.evlrs]
        assert [u for u, _ in evlrs].count("copc") == 1 and [v.user_id for v in f.header.vlrs].count("copc") == 1
    if name == "1_4_w_evlr.laz":
        assert len(evlrs) == 2
    if name == "Megaplot.laz":  # a CRS in GeoTIFF keys only: a WKT VLR added (the keys kept)
        with laspy.open(dst) as f:
            assert [(v.user_id, v.record_id) for v in f.header.vlrs if v.user_id == "LASF_Projection"] == [
                ("LASF_Projection", 34735), ("LASF_Projection", 2112)]
            assert f.header.parse_crs(prefer_wkt=True).to_epsg() == 26917


def test_octree_levels_match_a_single_build():
    """Subtree builds from every node at depth 2 give the levels of one build over the whole cloud."""
    src = laspy.read(shared_file("autzen_trim.laz"))
    xyz = np.stack([src.x, src.y, src.z], axis=1)
    origin, size = root_cube(np.stack([xyz.min(0), xyz.max(0)]))
    keys = point_keys(xyz, origin, size)
    keys = keys[np.argsort(keys >> (3 * (KEY_DEPTH - GRID_BITS)), kind="stable")]
    whole = assign_levels(keys, leaf_points=2_000)
    node = keys >> (3 * (KEY_DEPTH - 2))
    big = np.bincount(node).max()
    assert big > 2_000
    for k in np.unique(node):
        at = np.flatnonzero(node == k)
        if len(at) > 2_000:  # ancestors of depth-2 nodes are split; a small depth-2 node's parent may be a leaf
            np.testing.assert_array_equal(assign_levels(keys[at], base_depth=2, leaf_points=2_000), whole[at])
    _, depths, _, counts = group_nodes(keys, whole)
    assert counts.sum() == len(keys) and depths.max() >= 3 and np.all(counts[depths == 0] <= 128**3)


def test_hierarchy_in_pages(tmp_path):
    """A file whose hierarchy is cut into pages (every 4 levels) reads the same as with one page."""
    from cloudsieve.io import open_reader
    from cloudsieve.io.las_header import header_from_dict
    from cloudsieve.store.copc_file import compress, copc_header, laz_vlr, point_records, record_stats, write_copc
    from cloudsieve.store.octree import demorton

    copclib = pytest.importorskip("copclib")
    with open_reader(str(shared_file("autzen_trim.laz"))) as reader:
        parts = [arrays for _, arrays in reader.chunks()]
        header, dtypes, fmt = reader.header, reader.dtypes, reader.format
    arrays = {n: np.concatenate([p[n] for p in parts]) for n in parts[0]}
    bounds = np.stack([arrays["xyz"].min(axis=0), arrays["xyz"].max(axis=0)])
    origin, size = root_cube(bounds)
    # leaves of at most 40 points: nodes down to depth 4, where the pages start
    pkeys = point_keys(arrays["xyz"], origin, size)
    order, depths, keys, counts = group_nodes(pkeys, assign_levels(pkeys, leaf_points=40))
    hd, mapping = copc_header(header, dtypes, fmt, bounds)
    hdr, _ = header_from_dict(hd)
    records = point_records(arrays, hdr, mapping)[order]
    vlr, ends = laz_vlr(hdr), np.cumsum(counts)
    chunks = [compress(records[e - c:e], vlr) for c, e in zip(counts, ends)]
    (tmp_path / "chunks.bin").write_bytes(b"".join(chunks))
    nbytes = np.array([len(c) for c in chunks])
    cells_ = demorton(keys)
    nodes = {"depth": depths, "x": cells_[:, 0], "y": cells_[:, 1], "z": cells_[:, 2], "count": counts,
             "nbytes": nbytes, "source": np.zeros(len(counts), dtype=np.int64), "offset": np.cumsum(nbytes) - nbytes}
    stats = record_stats(records, hdr.point_format)
    one, paged = str(tmp_path / "one.copc.laz"), str(tmp_path / "paged.copc.laz")
    write_copc(one, hd, origin, size, nodes, [str(tmp_path / "chunks.bin")], stats, root_nodes=len(counts))
    write_copc(paged, hd, origin, size, nodes, [str(tmp_path / "chunks.bin")], stats, root_nodes=8)
    assert depths.max() >= 4 and np.sum(depths == 4) > 8
    box = laspy.copc.Bounds(mins=np.array([636400.0, 849100.0, 400.0]), maxs=np.array([636900.0, 849300.0, 450.0]))
    got = {}
    for path in (one, paged):
        with laspy.CopcReader.open(path) as reader:
            got[path] = (reader.copc_info.hierarchy_root_size // 32, reader.query(), reader.query(bounds=box))
        f = copclib.FileReader(path)
        assert len(f.GetAllNodes()) == len(counts) and f.ValidateSpatialBounds(False)
        assert len(f.GetPageList()) == (1 if path == one else 1 + len(np.unique(keys[depths == 4])))
    assert got[one][0] == len(counts) and got[paged][0] == np.sum(depths < 4) + len(np.unique(keys[depths == 4]))
    for i in (1, 2):
        want = {n: np.asarray(got[one][i][n]) for n in hdr.point_format.dimension_names}
        assert_same_records(got[paged][i], want)
    assert len(got[one][1]) == 110_000 and 100 < len(got[one][2]) < 110_000


def test_nested_hierarchy_pages_hold_every_entry_once():
    """Pages every level (step 1): followed from the root page, every entry found once, in the page of its root."""
    from cloudsieve.store.copc_hierarchy import ENTRY_DTYPE, hierarchy_pages
    from cloudsieve.store.octree import demorton

    src = laspy.read(shared_file("autzen_trim.laz"))
    xyz = np.stack([src.x, src.y, src.z], axis=1)
    origin, size = root_cube(np.stack([xyz.min(0), xyz.max(0)]))
    pkeys = point_keys(xyz, origin, size)
    _, depths, keys, counts = group_nodes(pkeys, assign_levels(pkeys, leaf_points=40))
    entries = np.zeros(len(depths), dtype=ENTRY_DTYPE)
    c = demorton(keys)
    entries["d"], entries["x"], entries["y"], entries["z"] = depths, c[:, 0], c[:, 1], c[:, 2]
    entries["count"], entries["offset"], entries["nbytes"] = counts, np.arange(len(depths)) * 100, 7
    at = 1000
    data, root_size = hierarchy_pages(entries, at, step=1, root_nodes=4)
    pages = [(at, root_size, None)]
    found = []
    while pages:
        offset, nbytes, root = pages.pop()
        page = np.frombuffer(data[offset - at:offset - at + nbytes], dtype=ENTRY_DTYPE)
        nodes = page[page["count"] >= 0]
        if root is not None:  # a page holds its root node and that node's children
            assert tuple(nodes[0][["d", "x", "y", "z"]].tolist()) == root
            assert np.all(nodes["d"][1:] == root[0] + 1) if len(nodes) > 1 else True
        found += [tuple(e.tolist()) for e in nodes]
        pages += [(int(p["offset"]), int(p["nbytes"]), tuple(p[["d", "x", "y", "z"]].tolist()))
                  for p in page[page["count"] == -1]]
    assert sorted(found) == sorted(tuple(e.tolist()) for e in entries)
    assert len(data) == 32 * (2 * len(entries) - np.sum(depths == 0))  # one pointer per node below the root
