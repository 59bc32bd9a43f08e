"""Every bad input and bad destination: exception type, exact message, nothing left behind."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.cli import main
from cloudsieve.store import export, ingest
from cloudsieve.errors import (
    CloudsieveError,
    CorruptInputError,
    DestinationExistsError,
    DestinationNotWritableError,
    EmptyInputError,
    InputFormatError,
    InputIsDirectoryError,
    InputNotFoundError,
    InvalidPointsError,
    SameSourceDestinationError,
    StoreNotFoundError,
    UnknownFormatError,
)
from cloudsieve.io import detect_format, open_reader, open_writer, read_cloud
from cloudsieve.store import PointStore


def leftovers(folder, name: str) -> list[str]:
    """Files in *folder* named like *name* or its temporary files."""
    return [f for f in os.listdir(folder) if f == name or f.startswith("." + name + ".")]


def write_xyz(path, rows: list[str]) -> None:
    path.write_text("\n".join(rows) + "\n")


def patch(path, offset: int, data: bytes) -> None:
    with open(path, "r+b") as fh:
        fh.seek(offset)
        fh.write(data)


@pytest.fixture
def las_store(tmp_path):
    return ingest(shared_file("simple.las"), tmp_path / "s.zarr", chunk_size=300)


# ------------------------------------------------------------------ inputs
def test_missing_file(tmp_path):
    src = tmp_path / "nope.las"
    with pytest.raises(InputNotFoundError, match=re.escape(f"{src}: no such file")):
        ingest(src, tmp_path / "s.zarr")
    assert leftovers(tmp_path, "s.zarr") == []
    assert isinstance(InputNotFoundError("x"), FileNotFoundError)


def test_directory_as_file(tmp_path):
    folder = tmp_path / "scan.las"
    folder.mkdir()
    with pytest.raises(InputIsDirectoryError, match=re.escape(f"{folder} is a directory, not a point cloud file")):
        ingest(folder, tmp_path / "s.zarr")
    assert leftovers(tmp_path, "s.zarr") == []


def test_unknown_extension(tmp_path):
    src = tmp_path / "scan.foo"
    src.write_bytes(b"1 2 3\n")
    with pytest.raises(UnknownFormatError, match=re.escape(f"{src}: unknown point cloud format (extension .foo)")):
        ingest(src, tmp_path / "s.zarr")
    assert leftovers(tmp_path, "s.zarr") == []
    # --format overrides the extension
    store = ingest(src, tmp_path / "s.zarr", format="xyz")
    assert store.count == 1


def test_unknown_format_name(tmp_path):
    with pytest.raises(UnknownFormatError, match=re.escape("x.las: unknown format 'gltf'; known formats: las, laz, copc")):
        detect_format("x.las", "gltf")


@pytest.mark.parametrize("name,keep", [("simple.las", 20_000), ("simple.laz", 9_000), ("autzen_trim.laz", 300_000)])
def test_truncated_las_laz(tmp_path, name, keep):
    src = tmp_path / ("cut_" + name)
    src.write_bytes(shared_file(name).read_bytes()[:keep])
    with pytest.raises(CorruptInputError, match=re.escape(str(src)) + r".*truncated or corrupt"):
        ingest(src, tmp_path / "s.zarr", chunk_size=500)
    assert leftovers(tmp_path, "s.zarr") == []


def test_truncated_las_header(tmp_path):
    src = tmp_path / "cut.las"
    src.write_bytes(shared_file("simple.las").read_bytes()[:100])
    with pytest.raises(CorruptInputError, match=re.escape(f"{src}: not a valid LAS/LAZ file")):
        ingest(src, tmp_path / "s.zarr")
    assert leftovers(tmp_path, "s.zarr") == []


def test_corrupt_las_signature(tmp_path):
    src = tmp_path / "bad.las"
    data = bytearray(shared_file("simple.las").read_bytes())
    data[:4] = b"XXXX"
    src.write_bytes(bytes(data))
    with pytest.raises(CorruptInputError, match=re.escape(f"{src}: not a valid LAS/LAZ file")):
        ingest(src, tmp_path / "s.zarr")


def test_corrupt_laz_body(tmp_path):
    src = tmp_path / "bad.laz"
    data = bytearray(shared_file("autzen_trim.laz").read_bytes())
    data[len(data) // 2 : len(data) // 2 + 4096] = b"\xff" * 4096  # garbage inside the compressed points
    src.write_bytes(bytes(data))
    with pytest.raises(CorruptInputError, match=re.escape(str(src))):
        ingest(src, tmp_path / "s.zarr", chunk_size=20_000)
    assert leftovers(tmp_path, "s.zarr") == []


@pytest.mark.parametrize("delta,says,holds", [(+10, 1075, 1065), (-10, 1055, 1065)])
def test_las_header_count_disagrees(tmp_path, delta, says, holds):
    src = tmp_path / "count.las"
    src.write_bytes(shared_file("simple.las").read_bytes())
    patch(src, 107, (1065 + delta).to_bytes(4, "little"))  # legacy point count (LAS 1.2)
    with pytest.raises(CorruptInputError, match=re.escape(f"{src}: header says {says} points but the file holds data for")):
        ingest(src, tmp_path / "s.zarr")
    with pytest.raises(CorruptInputError, match=f"holds data for (only )?{holds}"):
        open_reader(src)
    assert leftovers(tmp_path, "s.zarr") == []


def test_laz_header_count_too_large(tmp_path):
    src = tmp_path / "count.laz"
    src.write_bytes(shared_file("simple.laz").read_bytes())
    patch(src, 107, (2000).to_bytes(4, "little"))
    with pytest.raises(CorruptInputError, match=re.escape(str(src)) + ".*(truncated or corrupt)"):
        ingest(src, tmp_path / "s.zarr", chunk_size=500)
    assert leftovers(tmp_path, "s.zarr") == []


def test_ply_without_xyz(tmp_path):
    src = tmp_path / "noxyz.ply"
    src.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float u\nproperty float v\nend_header\n1 2\n3 4\n")
    with pytest.raises(InputFormatError, match=re.escape(f"{src}: PLY vertex element has no x/y/z properties (found: u, v)")):
        ingest(src, tmp_path / "s.zarr")
    assert leftovers(tmp_path, "s.zarr") == []
    src2 = tmp_path / "faces.ply"
    src2.write_text("ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n")
    with pytest.raises(InputFormatError, match=re.escape(f"{src2}: PLY has no vertex element, so no x/y/z (elements: face)")):
        ingest(src2, tmp_path / "s.zarr")


def test_ply_truncated_binary(tmp_path):
    src = tmp_path / "cut.ply"
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    src.write_bytes(header + np.zeros(7 * 3, "<f4").tobytes())
    with pytest.raises(CorruptInputError, match=re.escape(f"{src}: header says 10 vertices but the file holds data for only 7 (truncated)")):
        ingest(src, tmp_path / "s.zarr")


def test_ply_not_ply(tmp_path):
    src = tmp_path / "fake.ply"
    src.write_bytes(b"solid cube\n")
    with pytest.raises(CorruptInputError, match=re.escape(f"{src}: not a PLY file")):
        ingest(src, tmp_path / "s.zarr")


@pytest.mark.parametrize(
    "rows,line,what",
    [
        (["x y z", "1 2 3", "4 5 6", "7 8", "1 1 1"], 4, "expected 3 values, found 2: '7 8'"),
        (["1 2 3", "4 5 6", "", "7 8 abc"], 4, "cannot read 'abc' as a number: '7 8 abc'"),
        (["x,y,z", "1,2,3", "4,,6"], 3, "cannot read '' as a number: '4,,6'"),
    ],
)
def test_xyz_bad_row_names_line(tmp_path, rows, line, what):
    src = tmp_path / "bad.xyz"
    write_xyz(src, rows)
    with pytest.raises(CorruptInputError, match=re.escape(f"{src}, line {line}: {what}")):
        ingest(src, tmp_path / "s.zarr", chunk_size=2)
    assert leftovers(tmp_path, "s.zarr") == []


def test_xyz_without_xyz_columns(tmp_path):
    src = tmp_path / "cols.csv"
    write_xyz(src, ["a,b,c", "1,2,3"])
    with pytest.raises(InputFormatError, match=re.escape(f"{src}: text cloud has no x/y/z column (columns: a, b, c)")):
        ingest(src, tmp_path / "s.zarr")


def test_nan_inf_refused_naming_count(tmp_path):
    src = tmp_path / "nan.xyz"
    write_xyz(src, ["1 2 3", "nan 2 3", "4 5 6", "7 inf 9", "1 1 -inf", "2 2 2"])
    with pytest.raises(
        InvalidPointsError,
        match=re.escape(
            f"{src}: 3 of 6 points have NaN or infinite coordinates (first: point 1); "
            "pass drop_invalid=True to drop them"
        ),
    ):
        ingest(src, tmp_path / "s.zarr", chunk_size=2)
    assert leftovers(tmp_path, "s.zarr") == []
    store = ingest(src, tmp_path / "s.zarr", chunk_size=2, drop_invalid=True)
    assert store.count == 3
    assert store.attrs["cloudsieve"]["dropped_invalid"] == 3
    np.testing.assert_array_equal(store.read("xyz"), [[1, 2, 3], [4, 5, 6], [2, 2, 2]])


def test_all_invalid_is_empty(tmp_path):
    src = tmp_path / "nan.xyz"
    write_xyz(src, ["nan nan nan", "inf 1 1"])
    with pytest.raises(EmptyInputError, match=re.escape(f"{src} holds no valid points: all 2 have NaN or infinite coordinates")):
        ingest(src, tmp_path / "s.zarr", drop_invalid=True)
    assert leftovers(tmp_path, "s.zarr") == []


def test_empty_inputs(tmp_path):
    zero = tmp_path / "zero.laz"
    zero.write_bytes(b"")
    with pytest.raises(EmptyInputError, match=re.escape(f"{zero} is empty (0 bytes)")):
        ingest(zero, tmp_path / "s.zarr")
    header_only = tmp_path / "header.xyz"
    header_only.write_text("x y z\n")
    with pytest.raises(EmptyInputError, match=re.escape(f"{header_only} holds no points")):
        ingest(header_only, tmp_path / "s.zarr")
    ply = tmp_path / "none.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    with pytest.raises(EmptyInputError, match=re.escape(f"{ply} holds no points")):
        ingest(ply, tmp_path / "s.zarr")
    import laspy

    las = tmp_path / "none.las"
    with laspy.open(las, mode="w", header=laspy.LasHeader(point_format=3, version="1.2")):
        pass
    with pytest.raises(EmptyInputError, match=re.escape(f"{las} holds no points")):
        ingest(las, tmp_path / "s.zarr")
    assert leftovers(tmp_path, "s.zarr") == []


# ------------------------------------------------------------ destinations
def test_destination_is_source(tmp_path, las_store):
    src = tmp_path / "a.xyz"
    write_xyz(src, ["1 2 3"])
    with pytest.raises(SameSourceDestinationError, match=re.escape(f"destination {src} is the source {src}")):
        ingest(src, src, overwrite=True)
    assert src.read_text() == "1 2 3\n"
    with pytest.raises(SameSourceDestinationError, match=re.escape(f"destination {las_store.path} is the source {las_store.path}")):
        export(las_store, las_store.path, format="las", overwrite=True)
    assert PointStore.open(las_store.path).count == 1065


def test_destination_exists(tmp_path, las_store):
    dst = tmp_path / "out.laz"
    dst.write_bytes(b"precious")
    with pytest.raises(DestinationExistsError, match=re.escape(f"{dst} exists; pass overwrite=True to replace it")):
        export(las_store, dst)
    assert dst.read_bytes() == b"precious"
    assert leftovers(tmp_path, "out.laz") == ["out.laz"]
    export(las_store, dst, overwrite=True)
    assert dst.stat().st_size > 8
    # the same for a store
    with pytest.raises(DestinationExistsError, match=re.escape(f"{las_store.path} exists (a folder); pass overwrite=True")):
        ingest(shared_file("simple.las"), las_store.path)
    store = ingest(shared_file("simple.laz"), las_store.path, overwrite=True)
    assert store.source_format == "laz"
    assert leftovers(tmp_path, "s.zarr") == ["s.zarr"]


def test_unwritable_destination(tmp_path, las_store):
    # Tests run as root, and chmod does not stop root: a destination whose
    # parent is a regular file (or a missing folder) cannot be written by anyone.
    blocker = tmp_path / "file"
    blocker.write_text("x")
    dst = blocker / "out.laz"
    with pytest.raises(DestinationNotWritableError, match=re.escape(f"cannot write {dst}: {blocker} is not a folder")):
        export(las_store, dst)
    missing = tmp_path / "missing" / "out.las"
    with pytest.raises(DestinationNotWritableError, match=re.escape(f"cannot write {missing}: folder {missing.parent} does not exist")):
        export(las_store, missing)
    with pytest.raises(DestinationNotWritableError, match=re.escape(f"cannot write {blocker / 's.zarr'}: {blocker} is not a folder")):
        ingest(shared_file("simple.las"), blocker / "s.zarr")
    # /proc refuses new files even to root
    proc = "/proc/cloudsieve-test.las"
    with pytest.raises(DestinationNotWritableError, match=re.escape(f"cannot write {proc}:")):
        export(las_store, proc)
    assert not os.path.exists(proc)
    assert isinstance(DestinationNotWritableError("x"), PermissionError)


def test_failed_write_leaves_nothing(tmp_path, las_store):
    """An error in the middle of a write removes the temporary file."""
    dst = tmp_path / "half.las"
    with pytest.raises(RuntimeError, match="boom"):
        with open_writer(dst, header=las_store.header, dtypes=las_store.dtypes, source_format="las") as w:
            for _, chunk in las_store.chunks(chunk_size=100):
                w.write(chunk)
                raise RuntimeError("boom")
    assert leftovers(tmp_path, "half.las") == []


def test_las_coordinates_out_of_range(tmp_path, las_store):
    xyz = np.array([[1e12, 0.0, 0.0]])
    dst = tmp_path / "far.las"
    with pytest.raises(InputFormatError, match=re.escape(f"cannot write {dst}: x values 1000000000000.0..1000000000000.0 do not fit LAS int32")):
        with open_writer(dst, header=las_store.header, dtypes={"xyz": (np.float64, (3,))}, source_format="las") as w:
            w.write({"xyz": xyz})
    assert leftovers(tmp_path, "far.las") == []


# ------------------------------------------------------------------ stores
def test_store_not_found(tmp_path):
    with pytest.raises(StoreNotFoundError, match=re.escape(f"{tmp_path / 'none.zarr'}: no such point store")):
        PointStore.open(tmp_path / "none.zarr")
    (tmp_path / "empty").mkdir()
    with pytest.raises(StoreNotFoundError, match=re.escape(f"{tmp_path / 'empty'} is not a cloudsieve point store")):
        PointStore.open(tmp_path / "empty")
    f = tmp_path / "scan.las"
    f.write_bytes(b"x")
    with pytest.raises(StoreNotFoundError, match=re.escape(f"{f} is a file, not a point store")):
        PointStore.open(f)
    with pytest.raises(StoreNotFoundError):
        export(tmp_path / "none.zarr", tmp_path / "o.las")
    assert leftovers(tmp_path, "o.las") == []


def test_bad_mask(tmp_path, las_store):
    with pytest.raises(ValueError, match=r"mask must be 1-D with 1065 entries \(one per point\), got shape \(3,\)"):
        export(las_store, tmp_path / "o.las", mask=np.ones(3, bool))
    with pytest.raises(ValueError, match="mask must be boolean, got dtype int64"):
        export(las_store, tmp_path / "o.las", mask=np.ones(1065, np.int64))
    with pytest.raises(KeyError, match="has no array 'simplify/keep'"):
        export(las_store, tmp_path / "o.las", mask="simplify/keep")
    assert leftovers(tmp_path, "o.las") == []


def test_read_cloud_errors(tmp_path):
    with pytest.raises(InputNotFoundError):
        read_cloud(tmp_path / "x.ply")
    assert issubclass(CorruptInputError, CloudsieveError) and issubclass(CorruptInputError, ValueError)


# --------------------------------------------------------------------- CLI
def test_cli_errors_exit_2_with_message(tmp_path, capsys):
    src = tmp_path / "missing.laz"
    assert main(["ingest", str(src), str(tmp_path / "s.zarr"), "--no-progress"]) == 2
    assert f"cloudsieve ingest: error: {src}: no such file" in capsys.readouterr().err

    bad = tmp_path / "nan.xyz"
    write_xyz(bad, ["1 2 3", "nan 1 1"])
    assert main(["ingest", str(bad), str(tmp_path / "s.zarr")]) == 2
    assert "cloudsieve ingest: error: " + f"{bad}: 1 of 2 points have NaN or infinite coordinates" in capsys.readouterr().err
    assert leftovers(tmp_path, "s.zarr") == []
    assert main(["ingest", str(bad), str(tmp_path / "s.zarr"), "--drop-invalid"]) == 0
    assert "dropped 1 points with NaN or infinite coordinates" in capsys.readouterr().err

    assert main(["export", str(tmp_path / "s.zarr"), str(tmp_path / "o.foo")]) == 2
    assert "cloudsieve export: error: " + f"{tmp_path / 'o.foo'}: unknown point cloud format (extension .foo)" in capsys.readouterr().err
    (tmp_path / "o.las").write_bytes(b"x")
    assert main(["export", str(tmp_path / "s.zarr"), str(tmp_path / "o.las")]) == 2
    assert "; pass --overwrite to replace it" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "s.zarr"), str(tmp_path / "o.las"), "--overwrite"]) == 0
    assert main(["info", str(tmp_path / "nowhere.las")]) == 2
    assert f"cloudsieve info: error: {tmp_path / 'nowhere.las'}: no such file" in capsys.readouterr().err
    folder = tmp_path / "folder"
    folder.mkdir()
    assert main(["info", str(folder)]) == 2
    assert f"{folder} is a directory, not a point cloud file or point store" in capsys.readouterr().err
