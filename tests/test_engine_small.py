"""A small input runs in memory (engine/small.py) and writes the bytes the work store's run writes.

The store's run is forced with ``scheduler="sync"`` (a scheduler chosen by
the caller always goes through the store); the default call of the same
options takes the in-memory path. Every shared LAS/LAZ/COPC scan, the PLY
scans, several output formats, a count, a seed, copies with and without
``keep_duplicates``, NaN points refused or dropped, and the degenerate
clouds (at most 8 points: no radius; one spot; copies) give the same file
(or error), the same summary counts and the same log lines; ``simplify_points`` with the rule ``eliminate``
keeps the points both write. Then: what decides the path, that it imports no zarr or dask, and that an exact
miss writes nothing.
"""

from __future__ import annotations

import logging
import subprocess
import sys

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.engine.small import IN_MEMORY_POINTS, SCHEDULER, fits_in_memory
from cloudsieve.errors import InvalidPointsError, TargetNotMetError
from cloudsieve.params import validate
from conftest import LAS_FILES, shared_file

COUNTS = ("points_in", "kept", "removed", "cells", "duplicates", "duplicates_kept")


def both(src, tmp_path, ext, caplog=None, **options):
    """(in-memory summary, store summary, their files' bytes, the log lines of each run)."""
    logs = []
    summaries = []
    for name, extra in (("memory", {}), ("store", {"scheduler": "sync"})):
        dst = tmp_path / f"{name}{ext}"
        if caplog is not None:
            caplog.clear()
        summaries.append(cloudsieve.simplify(src, dst, **options, **extra))
        if caplog is not None:
            logs.append([(r.levelname, r.getMessage().replace(str(dst), "DST")) for r in caplog.records
                         if r.name == "cloudsieve.engine.simplify" and r.levelno >= logging.INFO
                         and "points kept" not in r.getMessage()])
    small, store = summaries
    assert small.scheduler == SCHEDULER and store.scheduler == "sync"
    assert not list(tmp_path.glob("*.zarr"))  # neither run leaves a work store
    return small, store, (tmp_path / f"memory{ext}").read_bytes(), (tmp_path / f"store{ext}").read_bytes(), logs


@pytest.mark.parametrize("name", LAS_FILES)
def test_every_shared_scan_gives_the_store_runs_bytes(name, tmp_path):
    src = shared_file(name)
    ext = ".laz" if name.endswith(".laz") else ".las"
    small, store, a, b, _ = both(src, tmp_path, ext, ratio=0.3)
    assert [getattr(small, k) for k in COUNTS] == [getattr(store, k) for k in COUNTS]
    assert small.kept == round(0.3 * small.points_in)
    assert a == b


@pytest.mark.parametrize("ext", [".ply", ".xyz", ".laz"])
def test_other_formats_count_and_seed_give_the_same_bytes(ext, tmp_path):
    src = shared_file("autzen_trim.laz")  # above the 50,000 points of the radius's sample: the seed's draw
    small, store, a, b, _ = both(src, tmp_path, ext, count=12_345, seed=7)
    assert small.kept == store.kept == 12_345
    assert a == b


@pytest.mark.parametrize("name, ext", [("bun_zipper.ply", ".ply"), ("bun_zipper.ply", ".las"),
                                       ("maxplanck.ply", ".xyz")])
def test_a_ply_scan_gives_the_store_runs_bytes(name, ext, tmp_path):
    small, store, a, b, _ = both(shared_file(name), tmp_path, ext, ratio=0.25)
    assert [getattr(small, k) for k in COUNTS] == [getattr(store, k) for k in COUNTS]
    assert a == b


API = [("autzen_trim.laz", ".laz", {"ratio": 0.05}), ("bun_zipper.ply", ".ply", {"ratio": 0.3}),
       ("autzen_trim.laz", ".laz", {"count": 12_345, "seed": 7, "cluster_size": 200, "keep_duplicates": True})]


@pytest.mark.parametrize("name, ext, options", API, ids=[f"{n}-{sorted(o)}" for n, _, o in API])
def test_the_in_memory_api_keeps_the_runs_points(name, ext, options, tmp_path):
    """``simplify_points`` with the rule ``eliminate`` runs the engine's cells on the arrays: the points both
    runs write (autzen_trim: 110,000 points in k-d cells; at 5% in stages), and ``prune`` with the defaults."""
    xyz, _ = cloudsieve.read_cloud(shared_file(name))
    idx = cloudsieve.simplify_points(xyz, rule="eliminate", **options)
    _, _, a, b, _ = both(shared_file(name), tmp_path, ext, **options)
    assert a == b
    written, _ = cloudsieve.read_cloud(tmp_path / f"memory{ext}")
    assert np.array_equal(xyz[idx], written)
    if "seed" not in options:
        assert np.array_equal(np.flatnonzero(cloudsieve.prune(xyz, rule="eliminate", **options)), idx)


def _ply(path, pts):
    """*pts* as an ASCII PLY file (NaN kept as written)."""
    head = f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty double x\nproperty double y\n" \
           "property double z\nend_header\n"
    path.write_text(head + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in pts.tolist()))
    return path


def test_invalid_points_are_refused_or_dropped_as_the_store_run_does(tmp_path):
    pts = np.random.default_rng(1).random((500, 3))
    pts[[3, 70, 400], [0, 1, 2]] = [np.nan, np.inf, -np.inf]
    src = _ply(tmp_path / "nan.ply", pts)
    with pytest.raises(InvalidPointsError) as memory:
        cloudsieve.simplify(src, tmp_path / "a.ply", ratio=0.5)
    with pytest.raises(InvalidPointsError) as store:
        cloudsieve.simplify(src, tmp_path / "b.ply", ratio=0.5, scheduler="sync")
    assert str(memory.value) == str(store.value)
    small, store, a, b, _ = both(src, tmp_path, ".ply", ratio=0.5, drop_invalid=True)
    assert small.points_in == store.points_in == 497 and small.kept == store.kept == 248
    assert a == b


CELLS = [("autzen_trim.laz", 40_000, {"ratio": 0.5}), ("autzen_trim.laz", 20_000, {"count": 7_000, "seed": 3}),
         ("autzen_trim_7.las", 30_000, {"ratio": 0.1}), ("append-bug.laz", 10_000, {"ratio": 0.5}),
         ("Megaplot.laz", 25_000, {"ratio": 0.3, "keep_duplicates": True}), ("bun_zipper.ply", 10_000, {"ratio": 0.5})]


def test_several_store_chunks_give_the_store_runs_bytes(tmp_path):
    """Store chunks of 25,000 points: labelled chunk by chunk, written chunk by chunk; the LAS export in parts
    spliced (parts of 50,000 kept points) against one stream here."""
    for ext in (".laz", ".ply"):
        small, store, a, b, _ = both(shared_file("autzen_trim.laz"), tmp_path, ext, ratio=0.8, cell_size=30_000,
                                     chunk_size=25_000)
        assert small.kept == store.kept == 88_000 and a == b


@pytest.mark.parametrize("name, cell_size, options", CELLS, ids=[f"{n}-{c}" for n, c, _ in CELLS])
def test_several_cells_give_the_store_runs_bytes(name, cell_size, options, tmp_path):
    small, store, a, b, _ = both(shared_file(name), tmp_path, ".las", cell_size=cell_size, **options)
    assert small.cells == store.cells >= 3
    assert [getattr(small, k) for k in COUNTS] == [getattr(store, k) for k in COUNTS]
    assert a == b


def _las(path, pts):
    """*pts* as a LAS 1.2 file (scale 1e-6: distinct points stay distinct, copies stay copies)."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [1e-6] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.intensity = np.arange(len(pts), dtype=np.uint16)
    las.write(path)
    return path


def _with_copies(n, seed):
    rng = np.random.default_rng(seed)
    base = rng.random((max(1, n // 2), 3))
    return base[rng.integers(0, len(base), n)]


CLOUDS = {
    "random5": np.random.default_rng(5).random((5, 3)),  # at most 8 points: no radius
    "random20": np.random.default_rng(20).random((20, 3)),
    "one-spot1": np.full((1, 3), 1.5),
    "one-spot300": np.full((300, 3), 1.5),
    "copies12": _with_copies(12, 12),
    "copies2000": _with_copies(2_000, 3),
}
TABLE = [(c, r, k) for c in CLOUDS for r in (0.5, 0.1) for k in (False, True)]
CELL_SIZES = {"copies2000": 400}  # several cells of copies


@pytest.mark.parametrize("cloud,ratio,keep_duplicates", TABLE,
                         ids=[f"{c}-{r}{'-keepdup' if k else ''}" for c, r, k in TABLE])
def test_small_and_degenerate_clouds_give_the_same_file_counts_and_words(cloud, ratio, keep_duplicates, tmp_path,
                                                                        caplog):
    src = _las(tmp_path / f"{cloud}.las", CLOUDS[cloud])
    with caplog.at_level(logging.INFO, logger="cloudsieve"):
        small, store, a, b, logs = both(src, tmp_path, ".las", caplog, ratio=ratio, keep_duplicates=keep_duplicates,
                                        cell_size=CELL_SIZES.get(cloud, 200_000))
    assert [getattr(small, k) for k in COUNTS] == [getattr(store, k) for k in COUNTS]
    assert a == b
    assert logs[0] == logs[1]  # the duplicates and a missed target, said the same way


def test_exact_miss_writes_nothing(tmp_path):
    src = _las(tmp_path / "spot.las", np.full((300, 3), 1.5))
    with pytest.raises(TargetNotMetError, match="asked to keep 150 points, kept 1"):
        cloudsieve.simplify(src, tmp_path / "o.las", ratio=0.5, exact=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spot.las"]


def _fits(src, dst="o.las", **options):
    opts = validate("simplify", {"ratio": None if "count" in options else 0.5, **options})
    return fits_in_memory([str(src)], str(dst), opts, 1_065)


def test_what_runs_in_memory(tmp_path):
    las = shared_file("simple.las")
    assert _fits(las) and _fits(las, "o.ply") and _fits(las, "o.xyz") and _fits(las, count=10)
    assert _fits(las, cell_size=1_065) and _fits(las, cell_size=400)  # one cell or several
    assert _fits(las, chunk_size=1_000)  # several store chunks: written chunk by chunk
    opts = validate("simplify", {"ratio": 0.5})
    assert fits_in_memory([str(las)], "o.las", opts, IN_MEMORY_POINTS)
    assert not fits_in_memory([str(las)], "o.las", opts, IN_MEMORY_POINTS + 1)
    assert not _fits(las, "o.copc.laz")  # COPC is built from a store
    assert not _fits(las, tile_size=100.0)
    assert not _fits(las, store=str(tmp_path / "w.zarr"))  # a named store is kept: the run makes it
    assert not _fits(las, resume=True)
    assert not _fits(las, rule="target") and not _fits(las, ratio=None, threshold=0.001)  # the entropy rules use the store
    assert _fits(shared_file("bun_zipper.ply"))
    assert not _fits(shared_file("pumpAVisualReferenceImage.e57"))  # E57 and XYZ go through the store
    opts = validate("simplify", {"ratio": 0.5})
    assert not fits_in_memory([str(las)], "o.las", opts, None) and not fits_in_memory([str(las)], "o.las", opts, 0)


def test_a_chosen_scheduler_or_a_work_store_left_goes_through_the_store(tmp_path):
    src = shared_file("simple.las")
    assert cloudsieve.simplify(src, tmp_path / "a.las", ratio=0.5, workers=1).scheduler != SCHEDULER
    # a work store left by an interrupted run of the same source is reused, not ignored
    cloudsieve.simplify(src, tmp_path / "b.las", ratio=0.5, scheduler="sync", store=tmp_path / "b.las.cloudsieve.zarr")
    (tmp_path / "b.las").unlink()
    assert cloudsieve.simplify(src, tmp_path / "b.las", ratio=0.5).scheduler == "sync"


def test_a_small_run_imports_no_zarr_dask_or_scipy_spatial(tmp_path):
    """One cell: no store, no scheduler, and the radius's k-NN on the grid (scipy.spatial: 0.25 s to import)."""
    code = ("import sys, cloudsieve\n"
            f"s = cloudsieve.simplify({str(shared_file('autzen_trim.laz'))!r}, {str(tmp_path / 'o.laz')!r}, ratio=0.5)\n"
            "print(s.scheduler, sorted(m for m in ('zarr', 'dask', 'distributed', 'scipy.spatial') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == f"{SCHEDULER} []"


def test_after_ctrl_c_the_hint_names_a_work_store_only_when_there_is_one(tmp_path):
    from cloudsieve.cli import build_parser
    from cloudsieve.cli.simplify import interrupted_hint

    src = shared_file("simple.las")
    args = build_parser().parse_args(["simplify", str(src), str(tmp_path / "o.las"), "--ratio", "0.5"])
    assert interrupted_hint(args) == "; nothing to resume: run the same command again"  # in memory: none
    (tmp_path / "o.las.cloudsieve.zarr").mkdir()
    assert interrupted_hint(args) == ("; the work store is kept: run the same command again (or add --resume) to "
                                      "continue")
