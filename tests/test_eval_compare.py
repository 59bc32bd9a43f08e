"""Baselines (random, voxel, Poisson disk, FPS) and `cloudsieve compare`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_file
from scipy.spatial import cKDTree

from cloudsieve.cli import main
from cloudsieve.errors import CloudsieveError
from cloudsieve.evaluate.baselines import fps_subset, poisson_subset, random_subset, voxel_subset
from cloudsieve.io import open_writer, read_cloud


@pytest.fixture(scope="module")
def crop():
    """A crop of the Stanford bunny: the ~6000 points nearest its top."""
    xyz, _ = read_cloud(shared_file("bun_zipper.ply"))
    top = xyz[np.argmax(xyz[:, 1])]
    _, idx = cKDTree(xyz).query(top, k=6000)
    return xyz[np.sort(idx)]


def test_random_is_seeded_and_exact(crop):
    a = random_subset(crop, 1234, seed=3)
    assert len(a) == len(np.unique(a)) == 1234
    assert np.array_equal(a, random_subset(crop, 1234, seed=3))
    assert not np.array_equal(a, random_subset(crop, 1234, seed=4))


def test_voxel_keeps_the_point_nearest_each_centroid():
    # 2 x 2 x 1 voxels of known content: the count 4 is hit, each kept point is its voxel's nearest to the centroid
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.random((50, 3)) * 0.4 + [x, y, 0] for x in (0, 1) for y in (0, 1)])
    keep = voxel_subset(pts, 4)
    assert len(keep) == 4
    for k in keep:
        group = pts[np.all(np.abs(pts[:, :2] - np.floor(pts[k, :2]) - 0.2) <= 0.2, axis=1)]
        c = group.mean(axis=0)
        assert np.linalg.norm(pts[k] - c) == pytest.approx(np.linalg.norm(group - c, axis=1).min())


def test_voxel_and_poisson_hit_the_count(crop):
    for count in (600, 3000, 5400):
        assert abs(len(voxel_subset(crop, count)) - count) <= 0.01 * count
        assert abs(len(poisson_subset(crop, count)) - count) <= 0.01 * count


def test_poisson_is_a_disk_sample(crop):
    keep = poisson_subset(crop, 1500, seed=2)
    assert np.array_equal(keep, poisson_subset(crop, 1500, seed=2))
    kept = crop[keep]
    d, _ = cKDTree(kept).query(kept, k=2)
    dropped = np.setdiff1d(np.arange(len(crop)), keep)
    dd, _ = cKDTree(kept).query(crop[dropped])
    # a maximal disk sample of radius R: kept points are more than R apart, every dropped point within R of one
    assert dd.max() < d[:, 1].min()


def test_fps_subset_and_size_limit(crop):
    keep = fps_subset(crop, 500)
    assert len(keep) == 500 and np.array_equal(keep, fps_subset(crop, 500))
    with pytest.raises(CloudsieveError, match="fps: 6000 points x 500 kept = 3e\\+06 > 1e\\+06"):
        fps_subset(crop, 500, max_work=1e6)


def test_compare_cli_equal_counts_and_report(tmp_path, crop):
    src = tmp_path / "crop.ply"
    with open_writer(src, header={}, dtypes={"xyz": (np.dtype("float64"), (3,))}, format="ply") as w:
        w.write({"xyz": crop})
    out = tmp_path / "cmp"
    assert main(["compare", str(src), "--ratio", "0.5", "--rule", "iterative", "--report", str(out),
                 "--no-progress"]) == 0
    rep = json.loads((out / "report.json").read_text())
    rows = {r["method"]: r for r in rep["rows"]}
    assert set(rows) == {"km", "fcm", "random", "voxel", "poisson", "fps"}
    for r in rows.values():
        assert "error" not in r, r
        assert abs(r["kept"] - 3000) <= 30
        for key in ("point_mean_pct", "point_rms_pct", "point_max_pct", "metro_mean_pct", "metro_max_pct",
                    "metro_rms_pct", "compact_share"):
            assert r[key] is not None and r[key] >= 0
    md = (out / "report.md").read_text()
    assert md.count("\n| ") >= 7 and "| poisson |" in md
    om = rep["original_mesh"]  # the crop's mesh: its rim, few holes, no note
    assert om["faces"] > 0 and 0 < om["border_edges"] < 0.1 * om["faces"]
    assert f"border edges per face: {om['border_edges'] / om['faces']:.3f})" in md and "whatever the sampling" not in md
    for png in ("compactness.png", "point_errors.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    sub = json.loads((out / "km" / "report.json").read_text())
    assert sub["point"]["backward"]["max"] == 0.0 and sub["method"]["rule"] == "iterative"


def test_compare_needs_a_count(crop):
    from cloudsieve.evaluate import compare

    with pytest.raises(ValueError, match="needs --ratio or --count"):
        compare(crop, methods=["random", "voxel"])


def test_compare_bad_arguments_are_clear(crop, capsys):
    from cloudsieve.errors import InvalidParameterError
    from cloudsieve.evaluate import compare

    with pytest.raises(InvalidParameterError, match=r"unknown method\(s\) \['kmeans'\]; choose among km, fcm"):
        compare(crop, methods=["kmeans"], ratio=0.5)
    with pytest.raises(InvalidParameterError, match=r"unknown rule\(s\) \['fast'\]"):
        compare(crop, rule="iterative,fast", ratio=0.5)
    # a count above the points keeps them all, as on every surface, and says the count kept
    assert compare(crop, methods=["random"], count=7000, surface=False)["count"] == len(crop)
    assert main(["compare", str(shared_file("simple.las")), "--methods", "random,bogus", "--ratio", "0.5",
                 "--no-progress"]) == 2
    assert "unknown method(s) ['bogus']" in capsys.readouterr().err


def test_compare_runs_the_eliminate_rule_at_the_exact_count(crop, tmp_path, capsys):
    path = tmp_path / "crop.ply"
    with open_writer(path, header={}, dtypes={"xyz": (np.dtype("float64"), (3,))}, format="ply") as w:
        w.write({"xyz": crop})
    rc = main(["compare", str(path), "--methods", "km,voxel", "--rule", "eliminate", "--ratio", "0.2", "--no-surface",
               "--no-progress"])
    out = capsys.readouterr().out
    assert rc == 0
    row = next(line for line in out.splitlines() if line.startswith("| eliminate "))
    assert row.split("|")[2].strip() == "1,200"
    assert not any(line.startswith("| km") for line in out.splitlines())  # no clusters: one row, not one per method


def test_compare_runs_eliminate_once_whatever_the_methods():
    from cloudsieve.evaluate.compare import compare_runs

    assert compare_runs(["km", "fcm", "voxel"], ["coverage", "eliminate"]) == [
        ("km (coverage)", "km", "coverage"), ("eliminate", "km", "eliminate"), ("fcm (coverage)", "fcm", "coverage"),
        ("voxel", "voxel", None)]


def test_compare_notes_the_holes_of_the_original_mesh():
    """vegetation_1_3's mesh is about half border edges: compare's table says what that does to Metro."""
    from cloudsieve.evaluate import compare

    xyz, _ = read_cloud(shared_file("vegetation_1_3.las"))
    res = compare(xyz, methods=["voxel", "fps"], ratio=0.5)
    om = res["original_mesh"]
    assert om["border_edges"] > 0.1 * om["faces"]
    assert f"> The original's mesh has {om['border_edges'] / om['faces']:.3f} border edges per face" in res["markdown"]


def test_compare_states_eliminates_margin_over_the_best_baseline():
    from cloudsieve.evaluate.compare import compare

    a = np.random.default_rng(3).random((3000, 3)) * [1.0, 1.0, 0.05]
    res = compare(a, methods=("km", "voxel", "random"), ratio=0.2, surface=False)
    rows = {r["method"]: r for r in res["rows"]}
    best = {k: max(rows["voxel"][k], rows["random"][k]) for k in ("d1_psnr", "d2_psnr")}
    line = next(x for x in res["markdown"].splitlines() if x.startswith("eliminate against the best baseline"))
    assert f"D1 {rows['eliminate']['d1_psnr'] - best['d1_psnr']:+.2f} dB" in line
    assert f"D2 {rows['eliminate']['d2_psnr'] - best['d2_psnr']:+.2f} dB" in line


@pytest.mark.parametrize("tile_points", [200_000, 2_500])  # the whole crop as one tile; two tiles of 2,500 points
def test_compare_gives_each_method_its_own_surface_figures(crop, tile_points):
    """Each row's surface figures are those of that method's points alone, not the first method's."""
    from cloudsieve.evaluate import compare
    from cloudsieve.evaluate.baselines import run_method
    from cloudsieve.evaluate.surface import TilePlan, surface_errors

    methods = ("random", "voxel", "fps")
    res = compare(crop, methods=methods, ratio=0.5, tile_points=tile_points, seed=0)
    rows = {r["method"]: r for r in res["rows"]}
    keys = ("metro_mean_pct", "metro_max_pct", "metro_rms_pct", "compact_share", "faces", "metro_surface_mean_pct")
    assert len({tuple(rows[m][k] for k in keys) for m in methods}) == len(methods)
    for m in methods:
        idx = run_method(m, crop, res["count"], seed=0)
        alone = surface_errors(crop, crop[idx], TilePlan(tiles=4, tile_points=tile_points, seed=0))
        assert len(alone["tiles"]) == (1 if tile_points > len(crop) else 2)
        assert [rows[m][k] for k in keys] == [alone["mean_pct"], alone["max_pct"], alone["rms_pct"],
                                              alone["compact_share"], alone["faces"],
                                              alone["on_surface"]["mean_pct"]], m
