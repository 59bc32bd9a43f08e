"""Issue 27, item 5: a conversion says once what it drops and what it maps.

LAZ/COPC to PLY or XYZ drops the CRS (and the VLRs of the cloud); PLY to
LAZ drops the PLY comments and faces and maps a float ``intensity`` and
8-bit colours to the LAS fields; PLY to PLY keeps the comments. One warning
per written file, naming each field. Real scans, real files.
"""

from __future__ import annotations

import logging

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.io.ply import read_ply_header
from conftest import shared_file
from test_cli_help import cloudsieve as run_cli

OREGON = "NAD83 / Oregon LCC (m) + NAVD88 height (ftUS)"


def convert(src, dst, tmp_path, caplog):
    """ingest + export (what every conversion does), and the warnings logged meanwhile."""
    store = cloudsieve.ingest(src, tmp_path / "s.zarr", overwrite=True)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        cloudsieve.export(store, dst, overwrite=True)
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_laz_to_ply_says_the_crs_is_dropped(tmp_path, caplog):
    dst = tmp_path / "a.ply"
    assert convert(shared_file("autzen_trim.laz"), dst, tmp_path, caplog) == [
        f"{dst}: converting LAZ to PLY drops the CRS (NAD_1983_HARN_Lambert_Conformal_Conic): PLY has no CRS"]


def test_copc_to_xyz_through_simplify_says_it_once(tmp_path):
    dst = tmp_path / "s.xyz"
    proc = run_cli(["simplify", shared_file("simple.copc.laz"), dst, "--ratio", "0.5", "--scheduler", "sync",
                    "--no-progress"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == [
        f"WARNING cloudsieve.io._base: {dst}: converting COPC to XYZ drops the CRS ({OREGON}): XYZ has no CRS"]


def test_ply_to_laz_maps_intensity_and_drops_comments_and_faces(tmp_path, caplog):
    dst = tmp_path / "b.laz"
    assert convert(shared_file("bun_zipper.ply"), dst, tmp_path, caplog) == [
        f"{dst}: converting PLY to LAZ drops 1 PLY comment line(s) ('zipper output'), the 69,451 PLY face "
        "element(s); maps intensity to LAS intensity (values 0..1 x 65535 to 16 bits, clipped), intensity to the "
        "extra bytes 'intensity_' (unchanged)"]
    las = laspy.read(dst)
    intensity = cloudsieve.read_cloud(shared_file("bun_zipper.ply"))[1]["intensity"]
    assert 0 <= intensity.min() and intensity.max() <= 1
    np.testing.assert_array_equal(las.intensity, np.round(intensity.astype(np.float64) * 65535).astype(np.uint16))
    np.testing.assert_array_equal(np.asarray(las["intensity_"]), intensity)
    assert np.asarray(las["confidence"]).dtype == np.float32


def test_ply_colours_map_to_las_colours(tmp_path, caplog):
    n = 50
    rng = np.random.default_rng(0)
    xyz = rng.random((n, 3))
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    src = tmp_path / "c.ply"
    with cloudsieve.open_writer(src, header={}, dtypes={"xyz": ("f8", ()), "red": ("u1", ()), "green": ("u1", ()),
                                                         "blue": ("u1", ())}) as w:
        w.write({"xyz": xyz, "red": rgb[:, 0], "green": rgb[:, 1], "blue": rgb[:, 2]})
    dst = tmp_path / "c.las"
    assert convert(src, dst, tmp_path, caplog) == [
        f"{dst}: converting PLY to LAS drops 1 PLY comment line(s) ('written by cloudsieve'); maps red to LAS red "
        "(8-bit values x 257 to 16 bits), green to LAS green (8-bit values x 257 to 16 bits), blue to LAS blue "
        "(8-bit values x 257 to 16 bits)"]
    las = laspy.read(dst)
    np.testing.assert_array_equal(las.red, rgb[:, 0].astype(np.uint16) * 257)


def test_ply_to_ply_keeps_the_comments_and_says_the_faces_go(tmp_path, caplog):
    dst = tmp_path / "b.ply"
    assert convert(shared_file("bun_zipper.ply"), dst, tmp_path, caplog) == [
        f"{dst}: converting PLY to PLY drops the 69,451 PLY face element(s)"]
    assert "zipper output" in read_ply_header(str(dst))["comments"]


@pytest.mark.parametrize("name", ["simple.las", "autzen_trim.laz"])
def test_las_to_las_says_nothing(tmp_path, caplog, name):
    assert convert(shared_file(name), tmp_path / "o.laz", tmp_path, caplog) == []


def test_a_float_intensity_beyond_0_1_is_said_once(tmp_path, caplog):
    n = 30
    src = tmp_path / "i.ply"
    with cloudsieve.open_writer(src, header={}, dtypes={"xyz": ("f8", ()), "intensity": ("f4", ())}) as w:
        w.write({"xyz": np.random.default_rng(1).random((n, 3)), "intensity": np.arange(n, dtype=np.float32) * 10})
    dst = tmp_path / "i.las"
    messages = convert(src, dst, tmp_path, caplog)
    assert messages[1:] == [f"{dst}: intensity has values outside 0..1 (0..290): LAS intensity clipped to 0..65535"]
    las = laspy.read(dst)
    assert las.intensity.tolist() == [0] + [65535] * (n - 1)
    np.testing.assert_array_equal(np.asarray(las["intensity_"]), np.arange(n) * 10.0)  # the exact values kept
