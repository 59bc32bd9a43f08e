"""PLY, E57 and XYZ files; cross-format exports; Hypothesis round trips (the store API: test_store_pointstore.py)."""

from __future__ import annotations

import os

import laspy
import numpy as np
import pytest
from conftest import shared_file
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cloudsieve.cli import main
from cloudsieve.store import export, ingest
from cloudsieve.io import detect_format, open_reader, read_cloud
from cloudsieve.io.ply import read_ply_header


# ------------------------------------------------------------ real files
def test_bunny_ply():
    xyz, attrs = read_cloud(shared_file("bun_zipper.ply"))
    assert xyz.shape == (35_947, 3) and xyz.dtype == np.float64
    assert sorted(attrs) == ["confidence", "intensity"]
    assert attrs["confidence"].dtype == np.float32
    np.testing.assert_allclose(xyz.min(axis=0), [-0.0946899, 0.0329874, -0.0618736], atol=1e-7)
    np.testing.assert_allclose(xyz.max(axis=0), [0.0610091, 0.187321, 0.0587997], atol=1e-7)
    header = read_ply_header(shared_file("bun_zipper.ply"))
    assert header["format"] == "ascii"
    assert [e["name"] for e in header["elements"]] == ["vertex", "face"]


def test_maxplanck_ply_chunks():
    with open_reader(shared_file("maxplanck.ply"), chunk_size=4_000) as reader:
        assert reader.count == 25_445
        assert list(reader.dtypes) == ["xyz"]
        chunks = list(reader.chunks())
        sizes = [len(c.xyz) for c in chunks]
    assert sizes == [4_000] * 6 + [1_445]
    assert [c.start for c in chunks] == [4_000 * i for i in range(7)] and chunks[-1].stop == 25_445


def test_e57_pump():
    src = shared_file("pumpAVisualReferenceImage.e57")
    with open_reader(src, chunk_size=50_000) as reader:
        assert reader.count == 155_201
        assert reader.header["scan_count"] == 1
        sizes = [len(c.xyz) for c in reader.chunks()]
    assert sizes == [50_000, 50_000, 50_000, 5_201]
    xyz, attrs = read_cloud(src)
    for name in ("intensity", "colorRed", "colorGreen", "colorBlue", "rowIndex", "columnIndex"):
        assert name in attrs and len(attrs[name]) == 155_201
    assert attrs["colorRed"].dtype == np.uint8
    assert attrs["rowIndex"].max() == 1073 and attrs["columnIndex"].max() == 344
    assert 0.38 < attrs["intensity"].min() and attrs["intensity"].max() < 0.71
    np.testing.assert_allclose(xyz.min(axis=0), [-2.903763, -5.301102, -1.899704], atol=1e-5)
    # pye57's whole-scan read gives the same points
    import pye57

    raw = pye57.E57(str(src)).read_scan_raw(0)
    np.testing.assert_array_equal(xyz[:, 0], raw["cartesianX"])
    np.testing.assert_array_equal(attrs["colorBlue"], raw["colorBlue"])


def test_e57_to_las_store(tmp_path):
    store = ingest(shared_file("pumpAVisualReferenceImage.e57"), tmp_path / "s.zarr", chunk_size=40_000)
    export(store, tmp_path / "pump.laz")
    las = laspy.read(tmp_path / "pump.laz")
    assert las.header.point_count == 155_201
    assert las.point_format.id == 2  # colour, no GPS time
    xyz, attrs = read_cloud(shared_file("pumpAVisualReferenceImage.e57"))
    np.testing.assert_array_equal(np.asarray(las.red), attrs["colorRed"].astype(np.uint16) * 257)
    np.testing.assert_allclose(las.x, xyz[:, 0], atol=las.header.scales[0])
    np.testing.assert_array_equal(np.asarray(las["rowIndex"]), attrs["rowIndex"])
    np.testing.assert_array_equal(np.asarray(las["intensity_"]), attrs["intensity"])  # float: kept exactly as extra bytes
    expected = np.round(attrs["intensity"].astype(np.float64) * 65535).astype(np.uint16)  # and as LAS intensity
    np.testing.assert_array_equal(np.asarray(las.intensity), expected)


# ------------------------------------------------------------ round trips
def _same_cloud(a, b):
    xa, aa = a
    xb, ab = b
    np.testing.assert_array_equal(xb, xa)
    assert sorted(ab) == sorted(aa)
    for k in aa:
        np.testing.assert_array_equal(ab[k].astype(aa[k].dtype), aa[k], err_msg=k)


@pytest.mark.parametrize("ext", [".ply", ".xyz", ".csv", ".txt"])
def test_bunny_round_trip(tmp_path, ext):
    src = shared_file("bun_zipper.ply")
    store = ingest(src, tmp_path / "s.zarr", chunk_size=5_000)
    export(store, tmp_path / f"out{ext}", chunk_size=7_001)
    _same_cloud(read_cloud(src), read_cloud(tmp_path / f"out{ext}"))


def test_las_store_to_ply_and_xyz(tmp_path):
    src = shared_file("extrabytes.las")
    store = ingest(src, tmp_path / "s.zarr", chunk_size=400)
    export(store, tmp_path / "o.ply")
    export(store, tmp_path / "o.xyz")
    xyz, attrs = read_cloud(src)
    for out in ("o.ply", "o.xyz"):
        x2, a2 = read_cloud(tmp_path / out)
        np.testing.assert_array_equal(x2, xyz)
        np.testing.assert_array_equal(a2["classification"], attrs["classification"])
        np.testing.assert_array_equal(a2["Colors_1"], attrs["Colors"][:, 1])  # (n, 3) -> Colors_0..2
        np.testing.assert_array_equal(a2["gps_time"], attrs["gps_time"])
    # PLY from LAS: open3d reads it
    import open3d as o3d

    assert len(o3d.io.read_point_cloud(str(tmp_path / "o.ply")).points) == 1065


def test_ply_store_to_las(tmp_path):
    src = tmp_path / "c.ply"
    n = 500
    rng = np.random.default_rng(1)
    body = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("intensity", "<u2"), ("quality", "<f4")])
    for k in "xyz":
        body[k] = rng.uniform(-50, 50, n)
    for k in ("red", "green", "blue"):
        body[k] = rng.integers(0, 256, n)
    body["intensity"] = rng.integers(0, 60000, n)
    body["quality"] = rng.random(n)
    props = "".join(f"property {t} {k}\n" for k, t in [("x", "float"), ("y", "float"), ("z", "float"), ("red", "uchar"), ("green", "uchar"), ("blue", "uchar"), ("intensity", "ushort"), ("quality", "float")])
    src.write_bytes(f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n{props}end_header\n".encode() + body.tobytes())
    store = ingest(src, tmp_path / "s.zarr", chunk_size=64)
    export(store, tmp_path / "o.las")
    las = laspy.read(tmp_path / "o.las")
    assert las.point_format.id == 2
    assert las.header.version.minor == 4  # extra bytes
    np.testing.assert_allclose(las.x, body["x"], atol=las.header.scales[0])
    assert las.header.scales[0] <= 1e-6
    np.testing.assert_array_equal(np.asarray(las.red), body["red"].astype(np.uint16) * 257)
    np.testing.assert_array_equal(np.asarray(las.intensity), body["intensity"])
    np.testing.assert_array_equal(np.asarray(las["quality"]), body["quality"])


def test_big_endian_and_ascii_ply(tmp_path):
    rng = np.random.default_rng(2)
    xyz = rng.normal(size=(300, 3))
    ids = rng.integers(-1000, 1000, 300).astype(np.int32)
    dt = np.dtype([("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("id", ">i4")])
    body = np.zeros(300, dt)
    body["x"], body["y"], body["z"], body["id"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], ids
    head = "ply\nformat binary_big_endian 1.0\ncomment test\nelement vertex 300\nproperty double x\nproperty double y\nproperty double z\nproperty int id\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
    (tmp_path / "be.ply").write_bytes(head.encode() + body.tobytes())
    x1, a1 = read_cloud(tmp_path / "be.ply")
    np.testing.assert_array_equal(x1, xyz)
    np.testing.assert_array_equal(a1["id"], ids)
    assert a1["id"].dtype == np.int32 and a1["id"].dtype.isnative
    rows = "\n".join(f"{a!r} {b!r} {c!r} {i}" for (a, b, c), i in zip(xyz.tolist(), ids.tolist()))
    asc = head.replace("binary_big_endian", "ascii").replace("element face 0", "element face 1") + rows + "\n3 0 1 2\n"
    (tmp_path / "a.ply").write_text(asc)
    with open_reader(tmp_path / "a.ply", chunk_size=77) as reader:
        chunks = list(reader.chunks())
    assert [len(c.arrays["xyz"]) for c in chunks] == [77, 77, 77, 69]
    x2, a2 = read_cloud(tmp_path / "a.ply")
    np.testing.assert_array_equal(x2, xyz)
    np.testing.assert_array_equal(a2["id"], ids)


def test_xyz_header_delimiters_and_pts(tmp_path):
    (tmp_path / "a.csv").write_text("X;Y;Z;class\n1;2;3;4\n5;6;7;8\n")
    xyz, attrs = read_cloud(tmp_path / "a.csv")
    np.testing.assert_array_equal(xyz, [[1, 2, 3], [5, 6, 7]])
    np.testing.assert_array_equal(attrs["class"], [4, 8])
    (tmp_path / "b.pts").write_text("2\n1 2 3 10 255 0 0\n4 5 6 20 0 255 0\n")
    xyz, attrs = read_cloud(tmp_path / "b.pts")
    assert sorted(attrs) == ["blue", "green", "intensity", "red"]
    np.testing.assert_array_equal(attrs["green"], [0, 255])
    (tmp_path / "c.txt").write_text("# comment\n1\t2\t3\n\n4\t5\t6\n")
    xyz, attrs = read_cloud(tmp_path / "c.txt")
    np.testing.assert_array_equal(xyz, [[1, 2, 3], [4, 5, 6]])
    with open_reader(tmp_path / "c.txt", columns=["z", "y", "x"]) as reader:
        np.testing.assert_array_equal(next(reader.chunks()).xyz, [[3, 2, 1], [6, 5, 4]])
        assert reader.count is None


def test_detect_format():
    assert detect_format("a/B.COPC.LAZ") == "copc"
    assert detect_format("b.laz") == "laz"
    assert detect_format("c.pts") == "xyz"
    assert detect_format("c.pts", format="PLY") == "ply"


@st.composite
def clouds(draw):
    n = draw(st.integers(1, 60))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    scale = draw(st.sampled_from([1e-3, 1.0, 1e5]))
    xyz = rng.normal(size=(n, 3)) * scale
    attrs = {
        "intensity": rng.integers(0, 65535, n).astype(np.uint16),
        "value": rng.normal(size=n).astype(np.float32),
        "label": rng.integers(-100, 100, n).astype(np.int16),
    }
    return xyz, attrs


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cloud=clouds(), ext=st.sampled_from([".ply", ".xyz"]), chunk=st.integers(1, 25))
def test_hypothesis_round_trip(tmp_path_factory, cloud, ext, chunk):
    from cloudsieve.io import open_writer

    xyz, attrs = cloud
    folder = tmp_path_factory.mktemp("h")
    src = folder / f"src{ext}"
    dtypes = {"xyz": (np.float64, (3,)), **{k: (v.dtype, ()) for k, v in attrs.items()}}
    with open_writer(src, header={}, dtypes=dtypes) as w:
        for i in range(0, len(xyz), chunk):
            w.write({"xyz": xyz[i : i + chunk], **{k: v[i : i + chunk] for k, v in attrs.items()}})
    store = ingest(src, folder / "s.zarr", chunk_size=chunk)
    assert store.count == len(xyz)
    np.testing.assert_array_equal(store.bounds, [xyz.min(axis=0), xyz.max(axis=0)])
    export(store, folder / f"out{ext}", chunk_size=chunk + 3)
    x2, a2 = read_cloud(folder / f"out{ext}")
    np.testing.assert_array_equal(x2, xyz)
    for k, v in attrs.items():
        np.testing.assert_array_equal(a2[k].astype(v.dtype), v)


@settings(max_examples=10, deadline=None)
@given(cloud=clouds(), chunk=st.integers(1, 40))
def test_hypothesis_las_round_trip(tmp_path_factory, cloud, chunk):
    """Any cloud written to LAS with our header comes back within half a scale step."""
    xyz, attrs = cloud
    folder = tmp_path_factory.mktemp("l")
    src = folder / "src.xyz"
    with open(src, "w") as fh:
        fh.write("x y z intensity\n")
        for p, i in zip(xyz.tolist(), attrs["intensity"].tolist()):
            fh.write(f"{p[0]!r} {p[1]!r} {p[2]!r} {i}\n")
    store = ingest(src, folder / "s.zarr", chunk_size=chunk)
    export(store, folder / "o.las", chunk_size=chunk)
    las = laspy.read(folder / "o.las")
    tol = las.header.scales / 2 + 1e-9 * np.abs(xyz).max()
    assert np.all(np.abs(np.c_[las.x, las.y, las.z] - xyz) <= tol)
    store2 = ingest(folder / "o.las", folder / "s2.zarr", chunk_size=chunk + 1)
    export(store2, folder / "o2.las")
    assert (folder / "o2.las").read_bytes()[400:] == (folder / "o.las").read_bytes()[400:]


def test_cli_ingest_info_export(tmp_path, capsys):
    src = shared_file("autzen_trim.laz")
    store = tmp_path / "a.zarr"
    assert main(["ingest", str(src), str(store), "--chunk-size", "30000", "--no-progress"]) == 0
    assert "ingested 110000 points (16 attributes)" in capsys.readouterr().err
    assert main(["info", str(store)]) == 0
    out = capsys.readouterr().out
    assert "points      110,000" in out and "store (source laz)" in out and "NAD_1983_HARN_Lambert_Conformal_Conic" in out
    assert main(["info", str(src), "--json"]) == 0
    import json

    info = json.loads(capsys.readouterr().out)
    assert info["count"] == 110_000 and info["format"] == "laz" and "gps_time" in info["attributes"]
    assert main(["info", str(shared_file("bun_zipper.ply"))]) == 0
    out = capsys.readouterr().out
    assert "points      35,947" in out and "confidence (float32)" in out
    assert main(["export", str(store), str(tmp_path / "a.las"), "--chunk-size", "7777", "--no-progress"]) == 0
    las = laspy.read(tmp_path / "a.las")
    assert las.header.point_count == 110_000
    for cmd in ("info", "ingest", "export"):
        with pytest.raises(SystemExit) as exc:
            main([cmd, "--help"])
        assert exc.value.code == 0
        assert "usage: cloudsieve " + cmd in capsys.readouterr().out
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]
