"""Metro where the original's mesh has surface: samples facing a hole are left out and counted."""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve.evaluate.mesh import metro, on_border


def _grid(n: int, z: float, hole: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A unit square of 2 n^2 triangles at height z, without the cells inside ``hole`` = (lo, hi) on x and y."""
    g = np.linspace(0, 1, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    i, j = i.ravel(), j.ravel()
    if hole is not None:
        cx, cy = (i + 0.5) / n, (j + 0.5) / n
        keep = ~((cx > hole[0]) & (cx < hole[1]) & (cy > hole[0]) & (cy < hole[1]))
        i, j = i[keep], j[keep]
    a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
    return v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]).astype(np.int32)


def test_samples_over_the_hole_are_left_out():
    original = _grid(40, 0.0, hole=(0.3, 0.7))  # a 0.4 x 0.4 hole: 16% of the square
    simplified = _grid(20, 0.01)  # the whole square, 0.01 above
    m = metro(original, simplified, samples=40_000)
    b, on = m["backward"], m["backward"]["on_surface"]
    share = on["excluded"] / b["samples"]
    assert share == pytest.approx(0.16, abs=0.02)
    assert on["samples"] + on["excluded"] == b["samples"]
    assert on["mean"] == pytest.approx(0.01, rel=1e-3) and on["max"] == pytest.approx(0.01, rel=1e-3)
    assert b["mean"] > 1.5 * on["mean"] and b["max"] > 0.15  # the hole dominates the plain figure


def test_no_hole_nothing_left_out():
    m = metro(_grid(20, 0.0), _grid(10, 0.02), samples=5000)
    on = m["backward"]["on_surface"]
    assert on["excluded"] <= 0.02 * m["backward"]["samples"]  # the square's rim only
    assert on["mean"] == pytest.approx(0.02, rel=1e-3)


def test_on_border_finds_points_on_border_edges():
    v, f = _grid(4, 0.0, hole=(0.3, 0.7))  # the 4 middle cells out: a hole from 0.25 to 0.75
    pts = np.array([[0.5, 0.25, 0.0], [0.5, 0.5, 0.0], [0.125, 0.125, 0.0], [0.0, 0.3, 0.0]])
    assert on_border(pts, v, f, 1e-9).tolist() == [True, False, False, True]


def _write_mesh(path, mesh) -> str:
    v, f = mesh
    head = (f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty double x\nproperty double y\n"
            f"property double z\nelement face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    body = "\n".join(" ".join(map(repr, row)) for row in v.tolist())
    faces = "\n".join("3 " + " ".join(map(str, row)) for row in f.tolist())
    path.write_text(head + body + "\n" + faces + "\n")
    return str(path)


def test_reference_mesh_measures_both_meshes_against_it(tmp_path):
    from cloudsieve import evaluate

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.random(6000), rng.random(6000), np.full(6000, 0.004)])  # 0.004 above the reference
    ref = _write_mesh(tmp_path / "ref.ply", _grid(30, 0.0))
    rep = evaluate(pts, pts[::3], reference_mesh=ref)
    r = rep["surface"]["reference"]
    assert r["faces"] == 2 * 30 * 30
    diag = rep["diagonal"]
    for mesh in ("original", "simplified"):
        assert r[mesh]["backward"]["mean"] == pytest.approx(0.004, rel=0.05)  # samples on the cloud's mesh
        assert r[mesh]["backward"]["mean_pct"] == pytest.approx(100 * r[mesh]["backward"]["mean"] / diag)
    assert rep["parameters"]["reference_mesh"] == ref


def test_reference_mesh_errors(tmp_path):
    from cloudsieve import evaluate
    from cloudsieve.errors import InputFormatError, InputNotFoundError, InvalidParameterError

    pts = np.random.default_rng(1).random((50, 3))
    with pytest.raises(InvalidParameterError, match=r"^reference_mesh \(m.ply\) needs the surface level, which "
                                                    r"surface=False \(--no-surface\) turns off$"):
        evaluate(pts, pts[::2], surface=False, reference_mesh="m.ply")
    with pytest.raises(InputNotFoundError, match=r"^reference mesh not found: .*nothing\.ply$"):
        evaluate(pts, pts[::2], reference_mesh=str(tmp_path / "nothing.ply"))
    cloud = _write_mesh(tmp_path / "cloud.ply", (pts, np.zeros((0, 3), int)))
    with pytest.raises(InputFormatError, match=r"^the reference mesh .*cloud\.ply has no triangle \(50 vertices\)$"):
        evaluate(pts, pts[::2], reference_mesh=cloud)
