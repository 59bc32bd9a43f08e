"""The gap bound ``max_gap`` (``--max-gap D``) of the rule eliminate, against a brute-force oracle.

The oracle is scipy's k-d tree on every input point and every output point:
no input point is farther than D from the output, and the largest distance
is the one the summary states. The output holds the run without the bound
(a superset), the same bytes in memory, on the work store and on two
workers, as one file, tiles or COPC; far outliers are kept; a D above the
halo's margin fills to the margin; bad values and other rules are refused
with one exact message (exit 2).
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from scipy.spatial import cKDTree

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.errors import InvalidParameterError, ResumeMismatchError
from cloudsieve.io import read_cloud
from conftest import shared_file


def xyz(path) -> np.ndarray:
    return np.asarray(read_cloud(str(path))[0], dtype=np.float64)


def gap_of(points: np.ndarray, kept: np.ndarray) -> float:
    """The oracle: the largest distance from a point of *points* to the nearest of *kept*."""
    return float(cKDTree(kept).query(points)[0].max())


def rows(points: np.ndarray) -> set:
    return set(map(tuple, points.tolist()))


# (scan, options, D): D below the rule's own largest gap there, so the fill adds points
SCANS = [("bun_zipper.ply", {"ratio": 0.2, "cell_size": 5_000}, 0.0018),
         ("autzen_trim.laz", {"ratio": 0.1, "cell_size": 20_000}, 4.5),
         ("autzen_trim.laz", {"count": 30_000, "seed": 3}, 3.0)]


@pytest.mark.parametrize("name, options, gap", SCANS, ids=[f"{n}-{g}" for n, _, g in SCANS])
def test_no_point_ends_farther_than_the_bound_and_the_kept_set_only_grows(name, options, gap, tmp_path):
    src = shared_file(name)
    ext = ".ply" if name.endswith(".ply") else ".las"
    plain = cloudsieve.simplify(src, tmp_path / f"plain{ext}", **options)
    summary = cloudsieve.simplify(src, tmp_path / f"gap{ext}", max_gap=gap, **options)
    points, kept, before = xyz(src), xyz(tmp_path / f"gap{ext}"), xyz(tmp_path / f"plain{ext}")
    assert gap_of(points, before) > gap  # the rule alone leaves a wider gap
    found = gap_of(points, kept)
    assert found <= gap
    assert summary.gap["max"] == pytest.approx(found, rel=1e-12, abs=0)
    assert summary.gap["bound"] == gap and summary.gap["filled"] > 0
    assert summary.kept == plain.kept + summary.gap["filled"] == len(kept)
    assert rows(before) <= rows(kept)
    assert "gap" not in plain.to_dict() and summary.to_dict()["gap"] == summary.gap


def test_the_same_bytes_in_memory_on_the_store_and_on_two_workers(tmp_path):
    src, options = shared_file("autzen_trim.laz"), {"ratio": 0.2, "cell_size": 20_000, "max_gap": 3.0}
    runs = {"memory": {}, "sync": {"scheduler": "sync"}, "two": {"workers": 2, "store": tmp_path / "w.zarr"}}
    out = {}
    for name, extra in runs.items():
        summary = cloudsieve.simplify(src, tmp_path / f"{name}.laz", **options, **extra)
        out[name] = (tmp_path / f"{name}.laz").read_bytes(), summary.kept, summary.gap
    assert out["memory"] == out["sync"] == out["two"]
    assert out["memory"][2]["filled"] > 0


def test_tiles_and_copc_hold_the_points_of_one_file(tmp_path):
    src, options = shared_file("autzen_trim.laz"), {"ratio": 0.1, "cell_size": 30_000, "max_gap": 4.0}
    one = cloudsieve.simplify(src, tmp_path / "one.laz", **options)
    tiles = cloudsieve.simplify(src, tmp_path / "tiles", tile_size=300.0, **options)
    copc = cloudsieve.simplify(src, tmp_path / "out.copc.laz", **options)
    kept = xyz(tmp_path / "one.laz")
    tiled = np.concatenate([xyz(p) for p in sorted((tmp_path / "tiles").glob("*.laz"))])
    assert one.kept == tiles.kept == copc.kept == len(kept) == len(tiled)
    assert one.gap == tiles.gap == copc.gap and one.gap["filled"] > 0
    assert rows(tiled) == rows(kept) == rows(xyz(tmp_path / "out.copc.laz"))
    assert gap_of(xyz(src), kept) <= 4.0


def _las(path, pts):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [1e-3] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.write(path)
    return path


def _plane_with_outliers() -> tuple[np.ndarray, np.ndarray]:
    """A 70 x 70 grid of spacing 1 (z noise), some points copied, four far outliers, and a far pair 1 apart."""
    rng = np.random.default_rng(7)
    g = np.stack(np.meshgrid(np.arange(70.0), np.arange(70.0)), -1).reshape(-1, 2)
    plane = np.c_[g + rng.uniform(-0.2, 0.2, g.shape), rng.uniform(0, 0.3, len(g))]
    plane = np.round(np.concatenate([plane, plane[rng.integers(0, len(plane), 300)]]), 3)
    outliers = np.array([[200.0, 200.0, 0.0], [-150.0, 30.0, 5.0], [35.0, 35.0, 90.0], [300.0, -40.0, 0.0]])
    return np.concatenate([plane, outliers, [[250.0, 250.0, 0.0], [251.0, 250.0, 0.0]]]), outliers


@pytest.mark.parametrize("keep_duplicates", [False, True])
def test_far_outliers_are_kept_and_copies_follow_their_point(keep_duplicates, tmp_path):
    pts, outliers = _plane_with_outliers()
    src = _las(tmp_path / "plane.las", pts)
    summary = cloudsieve.simplify(src, tmp_path / "out.las", ratio=0.05, cell_size=1_000, max_gap=2.5,
                                  keep_duplicates=keep_duplicates)
    pts, kept = xyz(src), xyz(tmp_path / "out.las")  # as the file holds them (LAS integers)
    assert summary.cells >= 4 and summary.gap["filled"] > 0
    assert gap_of(pts, kept) <= 2.5 and rows(outliers) <= rows(kept)
    if keep_duplicates:  # every copy of a kept point, and no other copy
        _, first, copies = np.unique(pts, axis=0, return_index=True, return_counts=True)
        held = rows(kept)
        want = sum(int(c) for i, c in zip(first, copies) if tuple(pts[i].tolist()) in held)
        assert len(kept) == want


def test_a_bound_above_the_halo_fills_to_the_halo_and_adds_nothing_here(tmp_path):
    """bun_zipper in 8 cells: the margin is about 0.0094, the rule's own largest gap 0.0021 at 20%."""
    src = shared_file("bun_zipper.ply")
    cloudsieve.simplify(src, tmp_path / "plain.ply", ratio=0.2, cell_size=5_000)
    summary = cloudsieve.simplify(src, tmp_path / "gap.ply", ratio=0.2, cell_size=5_000, max_gap=1.0)
    assert summary.gap["fill_to"] < 0.01 and summary.gap["filled"] == 0
    assert summary.gap["max"] == pytest.approx(gap_of(xyz(src), xyz(tmp_path / "gap.ply")), rel=1e-12, abs=0)
    assert (tmp_path / "gap.ply").read_bytes() == (tmp_path / "plain.ply").read_bytes()


def test_a_work_store_of_a_run_with_the_bound_does_not_resume_another(tmp_path):
    src, store = shared_file("bun_zipper.ply"), tmp_path / "w.zarr"
    cloudsieve.simplify(src, tmp_path / "a.ply", ratio=0.2, max_gap=0.0018, scheduler="sync", store=store)
    with pytest.raises(ResumeMismatchError, match="max_gap: stored 0.0018, asked None"):
        cloudsieve.simplify(src, tmp_path / "b.ply", ratio=0.2, scheduler="sync", store=store)


@pytest.mark.parametrize("value, got", [("0", "0.0"), ("-1", "-1.0"), ("nan", "nan"), ("inf", "inf")])
def test_a_bound_that_is_not_a_positive_finite_number_is_refused(value, got, tmp_path, capsys):
    src = shared_file("simple.laz")
    capsys.readouterr()
    rc = main(["simplify", str(src), str(tmp_path / "o.laz"), "--ratio", "0.5", "--max-gap", value])
    assert rc == 2
    assert capsys.readouterr().err == f"cloudsieve simplify: error: --max-gap must be a finite number > 0, got {got}\n"
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InvalidParameterError, match=r"^max_gap must be a finite number > 0"):
        cloudsieve.simplify(src, tmp_path / "o.laz", ratio=0.5, max_gap=float(value))


def test_another_rule_with_a_bound_is_refused(tmp_path, capsys):
    src = shared_file("simple.laz")
    capsys.readouterr()
    rc = main(["simplify", str(src), str(tmp_path / "o.laz"), "--rule", "iterative", "--ratio", "0.5",
               "--max-gap", "1"])
    assert rc == 2
    assert capsys.readouterr().err == ("cloudsieve simplify: error: --max-gap needs the rule eliminate (the default), "
                                       "not rule 'iterative'\n")
    assert list(tmp_path.iterdir()) == []


def test_a_run_killed_during_the_fill_resumes_to_the_same_bytes(tmp_path):
    """SIGKILL at the third fill task (two cells filled): the rerun fills every cell again, the same file."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from cloudsieve.engine.pause import PAUSE_ENV

    src, dst, store, marker = shared_file("bun_zipper.ply"), tmp_path / "out.ply", tmp_path / "w.zarr", tmp_path / "p"
    cloudsieve.simplify(src, tmp_path / "whole.ply", ratio=0.2, cell_size=5_000, max_gap=0.0018)
    cmd = [sys.executable, "-m", "cloudsieve", "simplify", str(src), str(dst), "--ratio", "0.2", "--cell-size",
           "5000", "--max-gap", "0.0018", "--scheduler", "sync", "--store", str(store), "--no-progress"]
    driver = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                              env={**os.environ, PAUSE_ENV: f"task:cells: fill#3={marker}"})
    try:
        deadline = time.monotonic() + 300
        while not marker.exists() and driver.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert marker.exists(), "the run did not reach its third fill task"
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=60)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert not dst.exists()
    done = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert dst.read_bytes() == (tmp_path / "whole.ply").read_bytes()


def test_with_a_class_kept_whole_the_bound_holds_and_the_class_stays_whole(tmp_path):
    src = shared_file("autzen_trim.laz")
    options = {"ratio": 0.1, "keep_class": [2], "cell_size": 30_000}
    plain = cloudsieve.simplify(src, tmp_path / "plain.laz", **options)
    memory = cloudsieve.simplify(src, tmp_path / "memory.laz", max_gap=4.0, **options)
    store = cloudsieve.simplify(src, tmp_path / "store.laz", max_gap=4.0, scheduler="sync", **options)
    assert (tmp_path / "memory.laz").read_bytes() == (tmp_path / "store.laz").read_bytes()
    assert memory.gap == store.gap and memory.gap["filled"] > 0
    assert memory.kept == plain.kept + memory.gap["filled"]
    kept, points = xyz(tmp_path / "memory.laz"), xyz(src)
    assert gap_of(points, kept) <= 4.0 and rows(xyz(tmp_path / "plain.laz")) <= rows(kept)
    las = laspy.read(src)
    assert rows(points[np.asarray(las.classification) == 2]) <= rows(kept)
    assert [(c["points_in"], c["kept"]) for c in memory.classes["classes"] if c["class"] == 2] == [(26_107, 26_107)]
