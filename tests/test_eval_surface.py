"""Surface level on tiles: the whole cloud when small, bounded and spread tiles (meshes: test_eval_mesh.py)."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.evaluate.surface import choose_tiles, surface_errors


def _surface(n, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(4 * u[:, 0]) * np.cos(3 * u[:, 1])]


def test_surface_whole_cloud_when_small():
    a = _surface(4000, seed=2)
    r = surface_errors(a, a[::2], tiles=4, tile_points=10_000)
    assert len(r["tiles"]) == 1 and r["tiles"][0]["whole_cloud"]
    assert r["tiles"][0]["points_original"] == 4000
    assert r["vertices"] == 2000 and r["faces"] > 1000
    for key in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct", "compact_share"):
        assert np.isfinite(r[key])
    assert r["max"] == max(r["forward"]["max"], r["backward"]["max"])
    diag = np.linalg.norm(a.max(0) - a.min(0))
    assert r["forward"]["mean_pct"] == pytest.approx(100 * r["forward"]["mean"] / diag)
    # identical clouds: Metro distances ~ 0
    same = surface_errors(a, a, tiles=1, tile_points=10_000)
    assert same["max"] < 1e-9


def test_tiles_are_bounded_and_spread():
    a = _surface(40_000, seed=3)
    tiles = choose_tiles(a, 4, 3000, seed=0)
    assert len(tiles) == 4
    c = np.array([t["centre"] for t in tiles])
    assert np.min([np.linalg.norm(c[i] - c[j]) for i in range(4) for j in range(i)]) > 0.2
    r = surface_errors(a, a[::3], tiles=4, tile_points=3000, seed=0)
    assert len(r["tiles"]) == 4
    for t in r["tiles"]:
        assert 1000 <= t["points_original"] <= 3000
        d = np.linalg.norm(a - t["centre"], axis=1)
        assert t["points_original"] == int((d <= t["radius"]).sum())
        assert t["points_simplified"] == int((np.linalg.norm(a[::3] - t["centre"], axis=1) <= t["radius"]).sum())
    # same seed, same tiles
    assert choose_tiles(a, 4, 3000, seed=0) == tiles
