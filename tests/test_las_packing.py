"""The tiles' LAS point records built by the bucketing tasks (io/las.py's LasPacking, LasWriter.write_records).

Oracle: the writer's own assembly (``LasRecords.build``, what ``LasWriter.write`` writes) of the same points,
and the source file's raw records; every point format of the shared scans, extra bytes included.
"""

from __future__ import annotations

import pickle

import laspy
import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.errors import InputFormatError, InvalidParameterError
from cloudsieve.io import open_writer
from cloudsieve.io.las import LasPacking, laz_backend
from cloudsieve.store import ingest

SCANS = ["simple.las", "vegetation_1_3.las", "autzen_trim_7.las", "append-bug.laz", "1_4_w_evlr.laz",
         "extrabytes.las", "simple.copc.laz"]


def store_points(store) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(xyz float64, {attribute: values}) of every point of *store*, as a bucketing task reads a chunk."""
    rows = store.rows(0, store.count)
    return rows.pop("xyz"), rows


def selection(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, order): about half the rows, increasing, and their order by a random key (stable), as a
    bucketing task selects and orders a chunk's points."""
    rng = np.random.default_rng(seed)
    rows = np.flatnonzero(rng.random(count) < 0.5)
    return rows, np.argsort(rng.integers(0, 5, len(rows)), kind="stable")


@pytest.mark.parametrize("name", SCANS)
def test_packing_is_the_writers_assembly(tmp_path, name):
    store = ingest(shared_file(name), tmp_path / "s.zarr")
    xyz, arrays = store_points(store)
    rows, order = selection(store.count, 3)
    take = rows[order]
    packing = pickle.loads(pickle.dumps(LasPacking(store.header, store.dimensions, "out")))  # as a task gets it
    got = packing(xyz[rows], arrays, take, order)
    expected = packing._built().build({"xyz": xyz[take], **{d: v[take] for d, v in arrays.items()}}).array
    assert got.dtype == expected.dtype == packing.dtype()
    assert got.tobytes() == expected.tobytes()
    # and the source's raw records, in the same order
    src = laspy.read(str(shared_file(name))).points.array
    assert got.tobytes() == np.ascontiguousarray(src[take]).tobytes()


def test_packing_refuses_what_the_writer_refuses(tmp_path):
    store = ingest(shared_file("simple.las"), tmp_path / "s.zarr")
    xyz, arrays = store_points(store)
    arrays["return_number"] = arrays["return_number"].copy()
    arrays["return_number"][5] = 9  # 3 bits in point format 3
    take = order = np.arange(store.count)
    packing = LasPacking(store.header, store.dimensions, "out")
    with pytest.raises(InputFormatError, match=r"^cannot write out: dimension 'return_number': value 9 is greater "
                                               r"than allowed \(max: 7\)$"):
        packing(xyz, arrays, take, order)
    xyz = xyz.copy()
    xyz[3, 0] = 1e300
    arrays["return_number"][5] = 1
    with pytest.raises(InputFormatError, match=r"^cannot write out: x values .* do not fit LAS int32 with scale"):
        packing(xyz, arrays, take, order)


@pytest.mark.parametrize("name", ["append-bug.laz", "autzen_trim.laz"])
def test_write_records_writes_the_bytes_of_write(tmp_path, name):
    store = ingest(shared_file(name), tmp_path / "s.zarr")
    xyz, arrays = store_points(store)
    packing = LasPacking(store.header, store.dimensions, "out")
    take = order = np.arange(store.count)
    records = packing(xyz, arrays, take, order)
    paths = {}
    for how in ("write", "records", "records, one thread"):
        path = tmp_path / f"{how}.laz"
        options = {"laz_backend": laz_backend(parallel=False)} if how.endswith("thread") else {}
        with open_writer(path, header=store.header, dtypes=store.dtypes, source_format=store.source_format,
                         bounds=store.bounds, **options) as writer:
            for start in range(0, store.count, 30_000):  # several blocks, as a tile task writes them
                if how == "write":
                    writer.write({"xyz": xyz[start:start + 30_000],
                                  **{d: v[start:start + 30_000] for d, v in arrays.items()}})
                else:
                    writer.write_records(records[start:start + 30_000])
        paths[how] = path.read_bytes()
    assert paths["write"] == paths["records"] == paths["records, one thread"]
    with open_writer(tmp_path / "bad.laz", header=store.header, dtypes=store.dtypes,
                     source_format=store.source_format, bounds=store.bounds) as writer:
        with pytest.raises(InvalidParameterError, match=r"^cannot write .*bad\.laz: records of dtype .*, not point "
                                                        r"format \d+'s"):
            writer.write_records(np.zeros(3, dtype=[("X", "<i4")]))
