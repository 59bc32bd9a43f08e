"""Surface level on tiles: the whole cloud when small, bounded and spread tiles (meshes: test_eval_mesh.py)."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.evaluate.surface import TilePlan, choose_tiles, surface_errors
from cloudsieve.evaluate.tiles import SURFACE_RATE


def _surface(n, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(4 * u[:, 0]) * np.cos(3 * u[:, 1])]


def test_surface_whole_cloud_when_small():
    a = _surface(4000, seed=2)
    r = surface_errors(a, a[::2], TilePlan(tiles=4, tile_points=10_000))
    assert len(r["tiles"]) == 1 and r["tiles"][0]["whole_cloud"]
    assert r["tiles"][0]["points_original"] == 4000
    assert r["vertices"] == 2000 and r["faces"] > 1000
    for key in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct", "compact_share"):
        assert np.isfinite(r[key])
    assert r["max"] == max(r["forward"]["max"], r["backward"]["max"])
    diag = np.linalg.norm(a.max(0) - a.min(0))
    assert r["forward"]["mean_pct"] == pytest.approx(100 * r["forward"]["mean"] / diag)
    # identical clouds: Metro distances ~ 0
    same = surface_errors(a, a, TilePlan(tiles=1, tile_points=10_000))
    assert same["max"] < 1e-9


def test_border_edges_count_the_holes():
    """Each mesh's border edges (of one triangle) against a count per edge; a hole in the cloud adds border edges."""
    from collections import Counter

    from cloudsieve.evaluate.mesh import ball_pivoting, border_edges

    g = (np.stack(np.meshgrid(np.arange(64), np.arange(64)), -1).reshape(-1, 2) + 0.5) / 64
    g += np.random.default_rng(0).normal(0, 0.002, g.shape)
    a = np.c_[g, 0.1 * np.sin(4 * g[:, 0]) * np.cos(3 * g[:, 1])]  # a jittered grid: few holes in its mesh
    holed = a[np.hypot(a[:, 0] - 0.5, a[:, 1] - 0.5) > 0.15]
    for pts in (a, holed):
        v, f = ball_pivoting(pts)
        per_edge = Counter(tuple(sorted(e)) for t in f.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])))
        oracle = sorted(e for e, c in per_edge.items() if c == 1)
        assert border_edges(f).tolist() == [list(e) for e in oracle]
    r = surface_errors(a, a[::2], TilePlan(tiles=1, tile_points=10_000))
    h = surface_errors(holed, holed[::2], TilePlan(tiles=1, tile_points=10_000))
    rim = 2 * np.pi * 0.15 * 64  # the hole's rim, in grid steps (measured: 37 more border edges, 20 at half)
    assert h["original"]["border_edges"] - r["original"]["border_edges"] >= rim / 4
    assert h["simplified"]["border_edges"] - r["simplified"]["border_edges"] >= rim / 8
    assert r["original"]["border_edges"] < 0.05 * r["original"]["faces"]
    assert border_edges(np.zeros((0, 3), np.int32)).shape == (0, 2)


def test_tiles_are_bounded_and_spread():
    a = _surface(40_000, seed=3)
    tiles = choose_tiles(a, 4, 3000, seed=0)
    assert len(tiles) == 4
    c = np.array([t["centre"] for t in tiles])
    assert np.min([np.linalg.norm(c[i] - c[j]) for i in range(4) for j in range(i)]) > 0.2
    r = surface_errors(a, a[::3], TilePlan(tiles=4, tile_points=3000, seed=0))
    assert len(r["tiles"]) == 4
    for t in r["tiles"]:
        assert 1000 <= t["points_original"] <= 3000
        d = np.linalg.norm(a - t["centre"], axis=1)
        assert t["points_original"] == int((d <= t["radius"]).sum())
        assert t["points_simplified"] == int((np.linalg.norm(a[::3] - t["centre"], axis=1) <= t["radius"]).sum())
    # same seed, same tiles
    assert choose_tiles(a, 4, 3000, seed=0) == tiles


def test_surface_budget_samples_random_tiles_and_gives_their_spread():
    a = _surface(60_000, seed=5)
    r = surface_errors(a, a[::2], TilePlan(tile_points=8000, budget=40.0, seed=1))
    smp = r["sampling"]
    assert smp["mode"] == "budget" and smp["budget"] == 40.0 and smp["population"] == 60_000
    # sized by the measured rate, never by a clock: T = 4 tiles of rate * budget / T points, capped by M
    assert smp["rate"] == SURFACE_RATE and smp["tile_points"] == min(8000, int(SURFACE_RATE * 40.0 / 4))
    assert smp["tiles"] == len(r["tiles"]) == 4
    for t in r["tiles"]:
        assert 0 < t["points_original"] <= 8000 and t["seconds"] > 0
        d = np.linalg.norm(a - t["centre"], axis=1)  # a tile: the original points nearest its centre
        assert t["points_original"] == int((d <= t["radius"]).sum())
    assert smp["points_share"] == pytest.approx(sum(t["points_original"] for t in r["tiles"]) / 60_000)
    if len(r["tiles"]) > 1:
        for name in ("forward", "backward"):
            assert smp["spread"][name]["mean_pct_se"] >= 0
    from cloudsieve.evaluate.report import sampling_line

    assert "budget" in sampling_line(r) and "not timed" in sampling_line(r)
    # the same tiles and figures again: nothing depends on how long a tile took
    again = surface_errors(a, a[::2], TilePlan(tile_points=8000, budget=40.0, seed=1))
    strip = lambda t: {k: v for k, v in t.items() if k != "seconds"}  # noqa: E731
    assert [strip(t) for t in again["tiles"]] == [strip(t) for t in r["tiles"]]


def test_surface_full_puts_every_point_in_one_tile():
    a = _surface(9000, seed=6)
    b = a[::3]
    r = surface_errors(a, b, TilePlan(tile_points=4000, full=True, seed=0))
    assert r["sampling"]["mode"] == "full" and len(r["tiles"]) == 3
    assert sum(t["points_original"] for t in r["tiles"]) == len(a)
    assert sum(t["points_simplified"] for t in r["tiles"]) == len(b)
    assert np.isfinite(r["mean_pct"])
