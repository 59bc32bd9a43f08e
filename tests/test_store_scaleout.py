"""Many files in as one cloud, ingest and export as tasks: real tiles cut from the shared scans, real dask."""

from __future__ import annotations

import json
import re

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.engine.runner import Runner
from cloudsieve.errors import EmptyInputError, InputNotFoundError, MismatchedInputsError
from cloudsieve.io.sources import expand_sources
from cloudsieve.store import PointStore, export, ingest
from cloudsieve.store.export_las import export_las

from conftest import shared_file


def cut_tiles(src, folder, nx=2, ny=2, *, compress=True):
    """Cut *src* into nx * ny LAZ tiles by x/y (laspy), in file order; returns their paths (sorted)."""
    las = laspy.read(src)
    folder.mkdir(parents=True, exist_ok=True)
    x, y = np.asarray(las.x), np.asarray(las.y)
    ix = np.minimum((nx * (x - x.min()) / (np.ptp(x) + 1e-9)).astype(int), nx - 1)
    iy = np.minimum((ny * (y - y.min()) / (np.ptp(y) + 1e-9)).astype(int), ny - 1)
    paths = []
    for j in range(ny):
        for i in range(nx):
            sel = (ix == i) & (iy == j)
            out = laspy.LasData(las.header)
            out.points = las.points[sel]
            path = folder / f"tile_{j}_{i}.{'laz' if compress else 'las'}"
            out.write(path)
            paths.append(path)
    return sorted(paths)


def concatenated(paths):
    """Every attribute of *paths*, file after file, as laspy reads them (the oracle)."""
    parts = [laspy.read(p) for p in paths]
    return {name: np.concatenate([np.asarray(p[name]) for p in parts]) for name in ("X", "Y", "Z", "intensity",
                                                                                     "gps_time", "classification",
                                                                                     "red", "return_number")}


@pytest.fixture
def tiles(tmp_path):
    return cut_tiles(shared_file("autzen_trim.laz"), tmp_path / "tiles")


def test_sources_glob_directory_list(tiles, tmp_path):
    folder = tiles[0].parent
    assert expand_sources(str(folder / "*.laz")) == [str(p) for p in tiles]
    assert expand_sources(str(folder)) == [str(p) for p in tiles]
    lst = tmp_path / "tiles.lst"
    lst.write_text("# the tiles\n" + "\n".join(f"tiles/{p.name}" for p in reversed(tiles)) + "\n\n")
    assert expand_sources(str(lst)) == [str(p) for p in reversed(tiles)]
    assert expand_sources(str(tiles[0])) == [str(tiles[0])]
    with pytest.raises(EmptyInputError, match=re.escape(f"{folder}/*.las: the pattern matches no file")):
        expand_sources(str(folder / "*.las"))
    lst.write_text("tiles/missing.laz\n")
    with pytest.raises(InputNotFoundError, match=re.escape(f"{lst}, line 1: tiles/missing.laz: no such file")):
        expand_sources(str(lst))


def test_tiles_ingest_as_one_cloud_exactly(tiles, tmp_path):
    oracle = concatenated(tiles)
    # chunks of 7,000 points: tasks start inside files and inside LAZ chunks (50,000 points)
    st = ingest(str(tiles[0].parent / "*.laz"), tmp_path / "s.zarr", chunk_size=7000)
    assert st.count == len(oracle["X"]) == 110_000
    assert np.dtype(st.array("xyz").dtype) == np.int32  # the LAS integers
    raw = np.asarray(st.array("xyz")[:])
    for i, dim in enumerate("XYZ"):
        np.testing.assert_array_equal(raw[:, i], oracle[dim])
    for name in ("intensity", "gps_time", "classification", "red", "return_number"):
        np.testing.assert_array_equal(st.read(name), oracle[name])
    h = laspy.read(tiles[0]).header
    np.testing.assert_array_equal(st.read("xyz")[:, 0], oracle["X"] * h.scales[0] + h.offsets[0])
    assert st.header["crs"] == PointStore.open(ingest(tiles[0], tmp_path / "t.zarr").path).header["crs"]
    assert st.header["crs"]["wkt"]


def test_ingest_tasks_same_store_on_a_local_cluster(tiles, tmp_path):
    from distributed import Client, LocalCluster

    from cloudsieve.engine.runner import NO_HTTP_PORT

    a = ingest(str(tiles[0].parent), tmp_path / "a.zarr", chunk_size=20_000)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster, Client(cluster) as client:
        run = Runner(client=client)
        b = ingest(str(tiles[0].parent), tmp_path / "b.zarr", chunk_size=20_000, run=run)
        assert run.worker_cpu() > 0
    for name in a.dimensions:
        np.testing.assert_array_equal(np.asarray(a.array(name)[:]), np.asarray(b.array(name)[:]))
    assert a.header == b.header and a.bounds.tolist() == b.bounds.tolist()


def test_scales_and_offsets_policy(tmp_path):
    src = shared_file("simple.las")
    las = laspy.read(src)
    fine = laspy.read(src)
    # a tenth of the scale, the offset 30 fine steps away: every record exactly representable
    fine.change_scaling(scales=las.header.scales / 10, offsets=las.header.offsets + las.header.scales * 3)
    fine.write(tmp_path / "b.las")
    las.write(tmp_path / "a.las")
    st = ingest(str(tmp_path / "*.las"), tmp_path / "s.zarr")
    assert st.header["scales"] == (las.header.scales / 10).tolist()
    assert st.header["offsets"] == las.header.offsets.tolist()
    xyz = st.read("xyz")
    np.testing.assert_array_equal(xyz[: len(las)], xyz[len(las):])  # the same points, exactly
    raw = np.asarray(st.array("xyz")[: len(las)])
    np.testing.assert_array_equal(raw[:, 0], np.asarray(las.X) * 10)
    # a scale that is no whole number of the finest: refused, naming the file
    odd = laspy.read(tmp_path / "b.las")
    odd.change_scaling(scales=las.header.scales / 2.5)
    odd.write(tmp_path / "b.las")
    with pytest.raises(MismatchedInputsError, match=re.escape(
            f"{tmp_path / 'a.las'}: the x scale 0.01 is 2.5 steps of the cloud's x scale 0.004 (the finest, from "
            f"{tmp_path / 'b.las'}), not a whole number: its records are not exactly representable")):
        ingest(str(tmp_path / "*.las"), tmp_path / "t.zarr")
    assert not (tmp_path / "t.zarr").exists()


def test_mismatched_headers_are_refused(tmp_path):
    las = laspy.read(shared_file("simple.las"))
    las.write(tmp_path / "a.las")
    other = laspy.convert(las, point_format_id=1)
    other.write(tmp_path / "b.las")
    with pytest.raises(MismatchedInputsError, match=re.escape(
            f"{tmp_path / 'b.las'}: point format 1, but {tmp_path / 'a.las'} has 3: the files of one cloud must "
            f"share their point format")):
        ingest(str(tmp_path / "*.las"), tmp_path / "s.zarr")
    # a CRS in one file only
    auto = laspy.read(shared_file("autzen_trim.laz"))
    auto.write(tmp_path / "c.laz")
    bare = laspy.LasData(laspy.LasHeader(point_format=auto.header.point_format, version=auto.header.version))
    bare.header.scales, bare.header.offsets = auto.header.scales, auto.header.offsets
    bare.points = auto.points[:10].copy()
    bare.write(tmp_path / "d.laz")
    assert main(["ingest", str(tmp_path / "*.laz"), str(tmp_path / "t.zarr")]) == 2


def test_export_parts_give_the_bytes_of_one_stream(tmp_path):
    st = ingest(shared_file("autzen_trim.laz"), tmp_path / "s.zarr", chunk_size=30_000)
    keep = np.random.default_rng(3).random(st.count) < 0.7
    PointStore.open(st.path, "r+").create_array("simplify/keep", data=keep)
    for fmt in ("laz", "las"):
        # the oracle: one process writing the kept records in one stream
        export(st, tmp_path / f"stream.{fmt}", mask=np.asarray(keep))  # a numpy mask streams in one process
        export_las(PointStore.open(st.path), str(tmp_path / f"parts.{fmt}"), fmt=fmt, mask="simplify/keep",
                   part_size=50_000)
        assert (tmp_path / f"parts.{fmt}").read_bytes() == (tmp_path / f"stream.{fmt}").read_bytes()
    # nothing kept: one empty part, the same empty file
    PointStore.open(st.path, "r+").create_array("simplify/none", data=np.zeros(st.count, bool))
    export(st, tmp_path / "stream0.laz", mask=np.zeros(st.count, bool))
    assert export_las(PointStore.open(st.path), str(tmp_path / "parts0.laz"), fmt="laz", mask="simplify/none") == 0
    assert (tmp_path / "parts0.laz").read_bytes() == (tmp_path / "stream0.laz").read_bytes()


def test_export_parts_keep_evlrs(tmp_path):
    src = laspy.read(shared_file("1_4_w_evlr.laz"))
    big = laspy.LasData(src.header)
    big.points = laspy.ScaleAwarePointRecord(np.tile(src.points.array, 60), src.header.point_format,
                                             src.header.scales, src.header.offsets)
    big.evlrs = src.evlrs
    big.write(tmp_path / "big.laz")
    st = ingest(tmp_path / "big.laz", tmp_path / "s.zarr")
    export(st, tmp_path / "stream.laz", mask=np.ones(st.count, bool))
    export_las(st, str(tmp_path / "parts.laz"), fmt="laz", part_size=50_000)
    assert (tmp_path / "parts.laz").read_bytes() == (tmp_path / "stream.laz").read_bytes()
    back = laspy.read(tmp_path / "parts.laz")
    assert len(back.points) == 60_000 and len(back.evlrs) == len(src.evlrs) == 1


def test_simplify_tiles_equals_the_merged_file(tiles, tmp_path):
    merged = laspy.read(tiles[0])
    merged.points = laspy.ScaleAwarePointRecord(np.concatenate([laspy.read(p).points.array for p in tiles]),
                                                merged.header.point_format, merged.header.scales,
                                                merged.header.offsets)
    merged.write(tmp_path / "merged.laz")
    a = cloudsieve.simplify(str(tmp_path / "merged.laz"), tmp_path / "a.laz", ratio=0.3, seed=1, scheduler="sync",
                            cell_size=40_000)
    b = cloudsieve.simplify(str(tiles[0].parent / "*.laz"), tmp_path / "b.laz", ratio=0.3, seed=1, cell_size=40_000,
                            workers=2)
    assert a.kept == b.kept == 33_000
    ra, rb = laspy.read(tmp_path / "a.laz"), laspy.read(tmp_path / "b.laz")
    np.testing.assert_array_equal(ra.points.array, rb.points.array)
    assert b.cpu_seconds["workers"] > 0 and b.cpu_seconds["driver"] > 0
    # the workers' CPU split by stage: every stage, each part of the total
    assert list(b.stage_cpu) == ["ingest", "partition", "cells", "merge", "export"]
    assert all(v >= 0 for v in b.stage_cpu.values()) and b.stage_cpu["cells"] > 0
    assert sum(b.stage_cpu.values()) == pytest.approx(b.cpu_seconds["workers"])


def test_cli_json_reports_cpu(tiles, tmp_path, capsys):
    assert main(["simplify", str(tiles[0].parent), str(tmp_path / "o.laz"), "--ratio", "0.5", "--json",
                 "--no-progress"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["cpu_seconds"]) == {"driver", "workers"}
    assert out["stage_cpu"] == {}  # 110,000 points run in memory, in this process: no workers
    assert out["points_in"] == 110_000 and out["kept"] == 55_000


def test_pipeline_reads_a_glob_as_one_cloud(tiles, tmp_path):
    doc = {"pipeline": [{"type": "readers.las", "filename": str(tiles[0].parent / "*.laz"), "merge": True},
                        {"type": "filters.entropy", "ratio": 0.25, "seed": 2},
                        {"type": "writers.las", "filename": str(tmp_path / "out" / "{stem}.laz")}]}
    (tmp_path / "p.json").write_text(json.dumps(doc))
    assert main(["run", str(tmp_path / "p.json")]) == 0
    got = laspy.read(tmp_path / "out" / "tiles.laz")
    assert len(got.points) == 27_500
    assert main(["simplify", str(tiles[0].parent), str(tmp_path / "d.laz"), "--ratio", "0.25", "--seed", "2"]) == 0
    np.testing.assert_array_equal(laspy.read(tmp_path / "d.laz").points.array, got.points.array)
    doc["pipeline"].append({"type": "evaluate", "report_dir": str(tmp_path / "rep")})
    (tmp_path / "p.json").write_text(json.dumps(doc))
    assert main(["run", str(tmp_path / "p.json")]) == 2


def test_tiles_out_and_the_vpc_back_in(tiles, tmp_path):
    src = str(tiles[0].parent / "*.laz")
    assert main(["simplify", src, str(tmp_path / "one.laz"), "--ratio", "0.4", "--no-progress"]) == 0
    assert main(["simplify", src, str(tmp_path / "tiled") + "/", "--ratio", "0.4", "--tile-size", "250",
                 "--no-progress"]) == 0  # a folder given with its slash
    vpc = tmp_path / "tiled" / "index.vpc"
    doc = json.loads(vpc.read_text())
    assert sum(f["properties"]["pc:count"] for f in doc["features"]) == 44_000
    # the tiles hold exactly the records of the one-file output (in tile order)
    one = laspy.read(tmp_path / "one.laz").points.array
    st = ingest(str(vpc), tmp_path / "back.zarr")
    assert st.count == len(one) == 44_000
    raw = np.asarray(st.array("xyz")[:])
    key = lambda a: np.lexsort(a.T[::-1])  # noqa: E731
    np.testing.assert_array_equal(raw[key(raw)], np.c_[one["X"], one["Y"], one["Z"]][key(np.c_[one["X"], one["Y"],
                                                                                                  one["Z"]])])
    # an existing folder is refused (exit 2) and left as it was
    before = sorted(p.name for p in (tmp_path / "tiled").iterdir())
    assert main(["simplify", src, str(tmp_path / "tiled"), "--ratio", "0.4", "--tile-size", "250"]) == 2
    assert sorted(p.name for p in (tmp_path / "tiled").iterdir()) == before


def test_tiles_in_one_copc_out(tiles, tmp_path):
    src = str(tiles[0].parent)
    assert main(["simplify", src, str(tmp_path / "one.laz"), "--ratio", "0.3", "--no-progress"]) == 0
    assert main(["simplify", src, str(tmp_path / "one.copc.laz"), "--ratio", "0.3", "--no-progress"]) == 0
    one = laspy.read(tmp_path / "one.laz")
    lo, hi = np.array([636400.0, 849100.0]), np.array([636800.0, 849300.0])
    inside = ((one.x >= lo[0]) & (one.x <= hi[0]) & (one.y >= lo[1]) & (one.y <= hi[1]))
    with laspy.CopcReader.open(str(tmp_path / "one.copc.laz")) as reader:
        assert reader.header.point_count == len(one.points) == 33_000
        got = reader.query(laspy.copc.Bounds(mins=lo, maxs=hi))
    assert len(got) == int(inside.sum()) > 0
    key = lambda x, y, t: np.lexsort((t, y, x))  # noqa: E731
    want = np.c_[one.X[inside], one.Y[inside], one.Z[inside]]
    have = np.c_[got.X, got.Y, got.Z]
    np.testing.assert_array_equal(have[key(have[:, 0], have[:, 1], have[:, 2])],
                                  want[key(want[:, 0], want[:, 1], want[:, 2])])
