"""benchmarks/make_scan.py: deterministic, streamed, realistic attributes (real tiles or synthetic)."""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path

import laspy
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def make_scan():
    spec = importlib.util.spec_from_file_location("make_scan", ROOT / "benchmarks" / "make_scan.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.mark.parametrize("real", [True, False])
def test_make_scan_deterministic(tmp_path, make_scan, real):
    if real:
        from conftest import shared_file

        shared_file("autzen_trim.laz")
    else:
        make_scan.AUTZEN = tmp_path / "absent.laz"  # the synthetic fallback
    n = 250_003
    a, b, c = tmp_path / "a.laz", tmp_path / "b.laz", tmp_path / "c.laz"
    assert make_scan.make_scan(n, str(a), seed=7, chunk=60_000) == n
    assert make_scan.make_scan(n, str(b), seed=7, chunk=100_000) == n
    make_scan.make_scan(n, str(c), seed=8, chunk=60_000)
    las = laspy.read(a)
    assert las.header.point_count == n
    np.testing.assert_array_equal(las.points.array, laspy.read(b).points.array)  # chunking does not matter
    assert digest(a) == digest(b)  # same bytes, whatever the write batches
    assert not np.array_equal(las.points.array, laspy.read(c).points.array)  # the seed does
    assert las.point_format.id == 3
    assert len(np.unique(las.classification)) >= 2
    assert np.ptp(las.gps_time) > 0 and np.ptp(las.red) > 0 and np.ptp(las.intensity) > 0
    assert np.all(np.asarray(las.return_number) <= np.asarray(las.number_of_returns))
    xyz = np.c_[las.x, las.y, las.z]
    assert len(np.unique(xyz, axis=0)) > 0.99 * n  # jittered tiles, not copies
