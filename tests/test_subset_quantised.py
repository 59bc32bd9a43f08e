"""Issue 27, item 6: ``evaluate --subset`` compares at the destination's quantisation.

A PLY simplified to LAZ stores each kept point on the LAS grid (scale and
offset), a few 1e-17 away from the PLY's float; it is still a subset. A point
moved further than the grid explains is not.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from conftest import shared_file
from test_cli_help import cloudsieve


@pytest.fixture(scope="module")
def bunny_laz(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bunny")
    proc = cloudsieve(["simplify", shared_file("bun_zipper.ply"), folder / "b.laz", "--ratio", "0.5", "--scheduler",
                       "sync", "--no-progress"], folder)
    assert proc.returncode == 0, proc.stderr
    return folder / "b.laz"


def test_a_ply_simplified_to_laz_is_a_subset(bunny_laz, tmp_path):
    proc = cloudsieve(["evaluate", shared_file("bun_zipper.ply"), bunny_laz, "--subset", "--no-surface",
                       "--no-progress"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "original 35,947 points, simplified 17,974" in proc.stdout


def test_a_point_moved_beyond_the_grid_is_not(bunny_laz, tmp_path):
    las = laspy.read(bunny_laz)
    las.X[7] += 10  # ten steps of the LAS grid
    moved = tmp_path / "moved.laz"
    las.write(moved)
    proc = cloudsieve(["evaluate", shared_file("bun_zipper.ply"), moved, "--subset", "--no-surface", "--no-progress"],
                      tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"cloudsieve evaluate: error: 1 of 17974 simplified points are not points of the "
                                  f"original {shared_file('bun_zipper.ply')} (e.g. [{float(las.x[7])!r}, ")
    assert proc.stderr.endswith(", 1e-08 away), but a subset was claimed\n")


def test_quantise_is_what_a_las_file_stores():
    from cloudsieve.evaluate.points import quantise

    xyz = np.random.default_rng(0).random((100, 3)).astype(np.float32).astype(np.float64)
    scales, offsets = np.array([1e-9, 1e-9, 1e-9]), np.array([-1.0, 0.0, 0.0])
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = scales, offsets
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    np.testing.assert_array_equal(quantise(xyz, (scales, offsets)), np.c_[las.x, las.y, las.z])
    assert quantise(xyz, None) is xyz
