"""Issue 48, item 9: a text cloud's integer columns are integers, and reach LAS unscaled."""

from __future__ import annotations

import logging

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.errors import CorruptInputError
from cloudsieve.io.xyz import TYPED_ROWS


def _write(path, xyz, columns: dict[str, list[str]]):
    """A text cloud: x y z and *columns* (name -> the text of each value), as written."""
    names = ["x", "y", "z", *columns]
    rows = [" ".join([f"{p[0]:.3f}", f"{p[1]:.3f}", f"{p[2]:.3f}", *(v[i] for v in columns.values())])
            for i, p in enumerate(xyz)]
    path.write_text(" ".join(names) + "\n" + "\n".join(rows) + "\n")
    return path


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_integer_intensities_reach_las_as_they_are(tmp_path, caplog):
    rng = np.random.default_rng(0)
    xyz = rng.random((3000, 3)) * 100
    intensity = rng.integers(0, 255, len(xyz))
    src = _write(tmp_path / "i.xyz", xyz, {"intensity": [str(v) for v in intensity]})
    _, attrs = cloudsieve.read_cloud(src)
    assert attrs["intensity"].dtype == np.int64 and attrs["intensity"].tolist() == intensity.tolist()
    with caplog.at_level(logging.WARNING):
        summary = cloudsieve.simplify(src, tmp_path / "o.las", ratio=0.5)
    assert _warnings(caplog) == []  # nothing scaled, nothing clipped
    las = laspy.read(tmp_path / "o.las")
    assert len(las) == summary.kept == 1500 and list(las.point_format.extra_dimension_names) == []
    source = {tuple(np.round(p, 3)): v for p, v in zip(xyz, intensity)}
    assert las.intensity.tolist() == [source[(x, y, z)] for x, y, z in np.round(np.c_[las.x, las.y, las.z], 3)]


def test_float_intensities_in_0_1_are_still_scaled(tmp_path):
    rng = np.random.default_rng(1)
    xyz = rng.random((200, 3)) * 10
    values = np.round(rng.random(len(xyz)), 4)
    src = _write(tmp_path / "f.xyz", xyz, {"intensity": [f"{v:.4f}" for v in values]})
    store = cloudsieve.ingest(src, tmp_path / "s.zarr")
    assert store.dtypes["intensity"][0] == np.float64
    cloudsieve.export(store, tmp_path / "f.las")
    las = laspy.read(tmp_path / "f.las")
    assert las.intensity.tolist() == np.round(values * 65535).astype(np.uint16).tolist()
    np.testing.assert_array_equal(np.asarray(las["intensity_"]), values)


def test_integers_beyond_the_las_field_are_clipped_and_said_once(tmp_path, caplog):
    xyz = np.random.default_rng(2).random((50, 3))
    intensity = np.arange(50) * 2000 - 5000  # -5,000 .. 93,000
    src = _write(tmp_path / "w.xyz", xyz, {"intensity": [str(v) for v in intensity], "gps_time": [str(v) for v in
                                                                                                  range(50)]})
    store = cloudsieve.ingest(src, tmp_path / "s.zarr")
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        cloudsieve.export(store, tmp_path / "w.las")
    assert _warnings(caplog) == [f"{tmp_path / 'w.las'}: intensity has values outside LAS intensity's 0..65535 "
                                 "(-5000..93000): clipped"]
    las = laspy.read(tmp_path / "w.las")
    assert las.intensity.tolist() == np.clip(intensity, 0, 65535).tolist()
    assert las.point_format.id == 1 and las.gps_time.tolist() == list(range(50))  # integer seconds: LAS gps_time


def test_a_fraction_after_the_typed_rows_names_its_line(tmp_path):
    n = TYPED_ROWS + 5
    xyz = np.random.default_rng(3).random((n, 3))
    values = [str(i % 7) for i in range(n)]
    values[TYPED_ROWS + 2] = "2.5"
    src = _write(tmp_path / "late.xyz", xyz, {"classification": values})
    with pytest.raises(CorruptInputError) as e:
        cloudsieve.read_cloud(src)
    assert str(e.value) == (
        f"{src}, line {TYPED_ROWS + 4}: column classification holds '2.5', not an integer of 64 bits, but its first "
        f"{TYPED_ROWS:,} rows hold integers only, so it is read as integers; write one of those with a decimal point "
        "(1.0) to read the column as floats")
    values[TYPED_ROWS + 2] = "3.0"  # a whole number written as a float: the integer 3
    _write(src, xyz, {"classification": values})
    assert cloudsieve.read_cloud(src)[1]["classification"][TYPED_ROWS + 2] == 3


def test_text_written_by_cloudsieve_reads_back_with_its_types(tmp_path):
    """Whole floats are written with a decimal point (1.0): a float column reads back as floats, integers as integers."""
    xyz = np.array([[0.5, 1.0, 2.0], [3.0, 4.25, 5.0]])
    arrays = {"xyz": xyz, "f64": np.array([1.0, 2.5]), "f32": np.array([3.0, 0.1], dtype=np.float32),
              "count": np.array([7, -8], dtype=np.int32)}
    dtypes = {k: (v.dtype, v.shape[1:]) for k, v in arrays.items()}
    with cloudsieve.open_writer(tmp_path / "t.xyz", header={}, dtypes=dtypes) as w:
        w.write(arrays)
    assert (tmp_path / "t.xyz").read_text().splitlines() == ["x y z f64 f32 count", "0.5 1.0 2.0 1.0 3.0 7",
                                                             "3.0 4.25 5.0 2.5 0.1 -8"]
    back, attrs = cloudsieve.read_cloud(tmp_path / "t.xyz")
    np.testing.assert_array_equal(back, xyz)
    assert {k: v.dtype for k, v in attrs.items()} == {"f64": np.float64, "f32": np.float64, "count": np.int64}
    assert attrs["f32"].astype(np.float32).tolist() == arrays["f32"].tolist()
