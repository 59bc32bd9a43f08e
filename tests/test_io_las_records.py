"""The LAS records' coordinates (io/las_records.py, core/kernels/records.py) against laspy and numpy.

The compiled pass over the record bytes is checked against the obvious numpy
code it replaced (fields copied, re-quantised in int64, cast, decoded), bit
for bit, and on real files against laspy's own X, Y, Z and attributes.
"""

from __future__ import annotations

import re

import laspy
import numpy as np
import pytest
from conftest import LAS_FILES, shared_file

from cloudsieve.core.kernels.records import las_xyz
from cloudsieve.errors import InputFormatError
from cloudsieve.io import las_records
from cloudsieve.io.las_records import decode_xyz, read_pieces

# a record with X, Y, Z not at the start, and a size no multiple of 4
_RECORD = np.dtype([("a", "u1"), ("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("b", "<u2"), ("c", "u1")])


def _records(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    arr = np.zeros(n, _RECORD)
    for f in ("X", "Y", "Z"):
        arr[f] = rng.integers(-(2**31), 2**31, n, dtype=np.int64)
    arr["X"][:4] = [-(2**31), 2**31 - 1, 0, -1]
    arr["a"], arr["c"] = rng.integers(0, 256, n), rng.integers(0, 256, n)
    return arr


def _kernel(arr, mult, add, scale, offset, decode: bool, ranges):
    n = len(arr)
    rec = arr.view(np.uint8).reshape(n, arr.dtype.itemsize)
    offs = np.array([arr.dtype.fields[f][1] for f in ("X", "Y", "Z")], dtype=np.int64)
    ints = np.empty((0 if decode else n, 3), dtype=np.int32)
    coords = np.empty((n if decode else 0, 3))
    lo, hi = np.full(3, np.iinfo(np.int64).max), np.full(3, np.iinfo(np.int64).min)
    for s, e in ranges:
        las_xyz(rec, offs, np.asarray(mult, dtype=np.int64), np.asarray(add, dtype=np.int64),
                np.asarray(scale, dtype=np.float64), np.asarray(offset, dtype=np.float64), ints, coords, s, e, lo, hi)
    return (coords if decode else ints), lo, hi


@pytest.mark.parametrize("scale, offset", [((0.01, 0.01, 0.01), (1000.5, -3.3, 0.0)),
                                           ((0.001, 1 / 3, 7e-5), (637000.0, 851000.0, 123.456)),
                                           ((1.0, 2.0, 0.5), (0.0, 0.0, 0.0))])
def test_the_coordinates_are_numpys_bit_for_bit(scale, offset):
    arr = _records(50_000)
    got, lo, hi = _kernel(arr, (1, 1, 1), (0, 0, 0), scale, offset, True, [(0, 20_000), (20_000, 50_000)])
    raw = np.stack([arr[f] for f in ("X", "Y", "Z")], axis=1)
    want = decode_xyz(raw.astype(np.int32), np.array(scale), np.array(offset))  # the store's decoding
    assert got.view(np.uint64).tolist() == want.view(np.uint64).tolist()
    assert lo.tolist() == raw.min(axis=0).tolist() and hi.tolist() == raw.max(axis=0).tolist()


def test_the_integers_are_re_quantised_in_int64():
    arr = _records(10_000, seed=1)
    for f in ("X", "Y", "Z"):
        arr[f] //= 16
    mult, add = (10, 1, 3), (5, -7, 0)
    got, lo, hi = _kernel(arr, mult, add, (1, 1, 1), (0, 0, 0), False, [(0, 10_000)])
    raw = np.stack([arr[f] for f in ("X", "Y", "Z")], axis=1).astype(np.int64) * mult + add
    assert lo.tolist() == raw.min(axis=0).tolist() and hi.tolist() == raw.max(axis=0).tolist()
    fits = np.all((raw >= -(2**31)) & (raw < 2**31), axis=1)
    assert got[fits].tolist() == raw[fits].tolist()


@pytest.mark.parametrize("name", ["autzen_trim.laz", "simple.las", "extrabytes.las", "1_4_w_evlr.laz"])
def test_read_pieces_gives_laspys_records(name, monkeypatch):
    assert name in LAS_FILES
    path = shared_file(name)
    las = laspy.read(path)
    n = len(las.points)
    names = ["intensity", "classification", "gps_time"]
    names = [x for x in names if x in las.point_format.dimension_names]
    pieces = [(path, 0, n // 3, ((1, 1, 1), (0, 0, 0))), (path, n // 3, n - n // 3, ((1, 1, 1), (0, 0, 0)))]
    ints, attrs, lo, hi = read_pieces(pieces, names)
    want = np.stack([las.X, las.Y, las.Z], axis=1)
    assert ints.dtype == np.int32 and ints.tolist() == want.tolist()
    assert lo.tolist() == want.min(axis=0).tolist() and hi.tolist() == want.max(axis=0).tolist()
    for x in names:
        assert np.asarray(attrs[x]).tolist() == np.asarray(las[x]).tolist()
    scale, offset = np.asarray(las.header.scales), np.asarray(las.header.offsets)
    monkeypatch.setattr(las_records, "THREADED_POINTS", 1)  # the attributes on threads beside X, Y, Z
    coords, attrs2, lo2, hi2 = read_pieces(pieces, names, parallel=True, decode=(scale, offset))
    assert coords.view(np.uint64).tolist() == decode_xyz(ints, scale, offset).view(np.uint64).tolist()
    assert lo2.tolist() == lo.tolist() and hi2.tolist() == hi.tolist()
    assert all(np.array_equal(attrs2[x], attrs[x]) for x in names)


@pytest.mark.parametrize("threaded", [False, True])
def test_integers_beyond_int32_after_re_quantising_name_the_file_and_points(threaded, monkeypatch):
    if threaded:
        monkeypatch.setattr(las_records, "THREADED_POINTS", 1)
    path = shared_file("simple.las")
    n = laspy.read(path).header.point_count
    pieces = [(path, 0, 10, ((1, 1, 1), (0, 0, 0))), (path, 10, n - 10, ((1, 2**20, 1), (0, 0, 0)))]
    with pytest.raises(InputFormatError, match=re.escape(
            f"{path}: re-quantised to the cloud's scale and offset, its coordinates do not fit LAS int32 "
            f"(points 10 to {n - 1})")):
        read_pieces(pieces, ["intensity"], parallel=True)
