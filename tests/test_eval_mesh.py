"""Meshes: compactness closed forms, Metro vs a direct pymeshlab call (tiles: test_eval_surface.py)."""

from __future__ import annotations

import math

import numpy as np
import pymeshlab
import pytest
from numpy.testing import assert_allclose

from cloudsieve.evaluate.mesh import ball_pivoting, compactness, compactness_summary, metro


def _tri(*pts):
    return np.array(pts, float), np.array([[0, 1, 2]])


def test_compactness_equilateral_is_one():
    v, f = _tri([0, 0, 0], [1, 0, 0], [0.5, math.sqrt(3) / 2, 0])
    assert compactness(v, f)[0] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("pts", [
    ([0, 0, 0], [1, 0, 0], [2, 0, 0]),      # collinear
    ([0, 0, 0], [1, 1, 1], [1, 1, 1]),      # two corners coincide
    ([3, 3, 3], [3, 3, 3], [3, 3, 3]),      # a point
])
def test_compactness_degenerate_is_zero(pts):
    assert compactness(*_tri(*pts))[0] == 0.0


def test_compactness_right_isosceles_closed_form():
    # legs 1, hypotenuse sqrt(2), area 1/2: c = 4 sqrt(3) (1/2) / (1 + 1 + 2) = sqrt(3) / 2
    v, f = _tri([0, 0, 0], [1, 0, 0], [0, 1, 0])
    assert compactness(v, f)[0] == pytest.approx(math.sqrt(3) / 2, abs=1e-12)


def test_compactness_is_invariant_to_scale_and_rotation():
    rng = np.random.default_rng(0)
    v = rng.random((30, 3))
    f = rng.integers(0, 30, (50, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    assert_allclose(compactness(v, f), compactness(1000 * v @ q.T + 5, f), atol=1e-9)


def test_compactness_equals_pymeshlab_mean_ratio():
    from conftest import shared_file

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(shared_file("bun_zipper.ply")))
    m = ms.current_mesh()
    ms.compute_scalar_by_aspect_ratio_per_face(metric="Mean ratio")
    ref = ms.current_mesh().face_scalar_array()
    ours = compactness(m.vertex_matrix(), m.face_matrix())
    assert_allclose(ours, ref, atol=1e-6)
    s = compactness_summary(ours)
    assert s["faces"] == 69_451
    assert s["compact_share"] == pytest.approx((ref >= 0.6).mean())
    assert sum(s["compactness_hist"]) == 69_451


def _surface(n, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(4 * u[:, 0]) * np.cos(3 * u[:, 1])]


_DIRECT = """
import json, sys
import numpy as np, pymeshlab
z = np.load(sys.argv[1])
s, t = sys.argv[2], sys.argv[3]
ms = pymeshlab.MeshSet()
ms.add_mesh(pymeshlab.Mesh(z["v" + s], z["f" + s]))
ms.add_mesh(pymeshlab.Mesh(z["v" + t], z["f" + t]))
r = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, samplevert=False, sampleface=True,
                              samplenum=50000, maxdist=pymeshlab.PureValue(float(sys.argv[4])))
print(json.dumps(r))
"""


def test_metro_equals_direct_pymeshlab_call(tmp_path):
    """Our figures equal a direct get_hausdorff_distance call, made first thing in a fresh process
    (pymeshlab's sampling RNG is process-wide and never reseeded, see cloudsieve.engine.calls.forked)."""
    import json
    import subprocess
    import sys

    a = _surface(3000)
    b = a[::2]
    ma, mb = ball_pivoting(a), ball_pivoting(b)
    assert len(ma[1]) > 3000 and len(mb[1]) > 1000
    ours = metro(ma, mb, samples=50_000)
    assert ours == metro(ma, mb, samples=50_000)  # reproducible
    np.savez(tmp_path / "m.npz", va=ma[0], fa=ma[1], vb=mb[0], fb=mb[1])
    allv = np.concatenate([ma[0], mb[0]])
    maxdist = 10.0 * float(np.linalg.norm(allv.max(0) - allv.min(0))) + 1e-12
    for name, (s, t) in (("forward", ("a", "b")), ("backward", ("b", "a"))):
        res = subprocess.run([sys.executable, "-c", _DIRECT, str(tmp_path / "m.npz"), s, t, repr(maxdist)],
                             capture_output=True, text=True, check=True)
        ref = json.loads(res.stdout.strip().splitlines()[-1])
        assert ours[name]["samples"] == ref["n_samples"] == 50_000  # no sample dropped
        for key, rkey in (("mean", "mean"), ("rms", "RMS"), ("max", "max"), ("min", "min")):
            assert ours[name][key] == ref[rkey]


def test_metro_keeps_far_samples_that_pymeshlab_defaults_drop():
    rng = np.random.default_rng(1)
    a = np.c_[rng.random((300, 2)), np.zeros(300)]
    far = a + [0, 0, 1.0]  # 1.0 away: beyond half the diagonal (sqrt(3)/2) of the two meshes' box
    ma, mf = ball_pivoting(a), ball_pivoting(far)
    ours = metro(ma, mf, samples=300)  # far apart meshes make vcg's grid search slow: few samples
    assert ours["forward"]["samples"] == ours["backward"]["samples"] == 300
    assert ours["forward"]["min"] == pytest.approx(1.0, rel=1e-6)
    assert ours["forward"]["max"] == pytest.approx(1.0, rel=1e-6)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(*ma))
    ms.add_mesh(pymeshlab.Mesh(*mf))
    default = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1)
    assert default["n_samples"] == 0  # vertices only, and every sample (1.0 away) dropped
