"""D1/D2 PSNR and Chamfer: against an independent k-d tree computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial import cKDTree

from cloudsieve import evaluate
from cloudsieve.errors import InvalidParameterError
from cloudsieve.evaluate.planes import K_NORMALS, pca_normals, psnr
from cloudsieve.evaluate.points import PointLevel, point_errors


def _normals_oracle(a: np.ndarray, k: int) -> np.ndarray:
    """PCA normals of every point of *a*: numpy's eigh on the k-NN covariance."""
    _, nb = cKDTree(a).query(a, k=k)
    x = a[nb] - a[nb].mean(axis=1, keepdims=True)
    _, v = np.linalg.eigh(np.einsum("cki,ckj->cij", x, x))
    return v[:, :, 0]


def _oracle(a: np.ndarray, b: np.ndarray, peak: float, k: int = K_NORMALS, normals: np.ndarray | None = None) -> dict:
    """pc_error's figures by brute force: whole-cloud trees, normals of A at A's point of each pair."""
    n = _normals_oracle(a, k) if normals is None else normals / np.linalg.norm(normals, axis=1, keepdims=True)
    _, jb = cKDTree(b).query(a)  # forward: a -> nearest b
    _, ja = cKDTree(a).query(b)  # backward: b -> nearest a
    ef, eb = b[jb] - a, b - a[ja]
    d1 = {"forward": (ef**2).sum(1).mean(), "backward": (eb**2).sum(1).mean()}
    d2 = {"forward": (np.einsum("ij,ij->i", ef, n) ** 2).mean(), "backward": (np.einsum("ij,ij->i", eb, n[ja]) ** 2).mean()}
    out = {}
    for name, m in (("d1", d1), ("d2", d2)):
        m["symmetric"] = max(m["forward"], m["backward"])
        out[name] = {key: (math.inf if v == 0 else 10 * math.log10(3 * peak**2 / v)) for key, v in m.items()}
    out["chamfer"] = d1["forward"] + d1["backward"]
    return out


def _surface(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u, v = rng.random(n), rng.random(n)
    return np.column_stack([u, v, 0.1 * np.sin(4 * u) * np.cos(3 * v)]) * [2.0, 1.0, 1.0]


@pytest.mark.parametrize("seed", [0, 1])
def test_psnr_and_chamfer_equal_brute_force(seed):
    a = _surface(4000, seed)
    rng = np.random.default_rng(seed + 10)
    keep = a[rng.choice(len(a), 800, replace=False)]
    moved = np.concatenate([keep, keep[:100] + rng.normal(scale=0.01, size=(100, 3))])
    rep = evaluate(a, moved, surface=False)
    diag = float(np.linalg.norm(a.max(0) - a.min(0)))
    want = _oracle(a, moved, diag)
    ps = rep["psnr"]
    assert ps["peak"] == pytest.approx(diag) and ps["peak_from"] == "diagonal"
    assert ps["normals"] == "estimated" and ps["k_normals"] == K_NORMALS
    for metric in ("d1", "d2"):
        for key in ("forward", "backward", "symmetric"):
            assert abs(ps[metric][key] - want[metric][key]) < 0.01, (metric, key)
    assert_allclose(rep["chamfer"]["value"], want["chamfer"], rtol=1e-9)
    assert rep["chamfer"]["value"] == pytest.approx(rep["chamfer"]["forward"] + rep["chamfer"]["backward"])


def test_subset_has_infinite_backward_psnr_and_the_given_peak():
    a = _surface(3000, 3)
    rep = evaluate(a, a[::4], surface=False, psnr_peak=30000.0)
    want = _oracle(a, a[::4], 30000.0)
    ps = rep["psnr"]
    assert ps["peak"] == 30000.0 and ps["peak_from"] == "given"
    assert ps["d1"]["backward"] == math.inf and ps["d2"]["backward"] == math.inf
    assert ps["d1"]["symmetric"] == pytest.approx(want["d1"]["forward"], abs=0.01)
    assert ps["d2"]["symmetric"] == pytest.approx(want["d2"]["forward"], abs=0.01)
    assert rep["chamfer"]["backward"] == 0


def test_d1_does_not_depend_on_chunks_and_d2_stays_close():
    a = _surface(6000, 4)
    b = a[::5] + np.random.default_rng(0).normal(scale=0.002, size=(1200, 3))
    one = point_errors(a, b)
    many = point_errors(a, b, PointLevel(chunk_size=1500))
    for d in ("forward", "backward"):
        assert_allclose(many[d]["mse"], one[d]["mse"], rtol=1e-12)
        assert_allclose(many[d]["d2_mse"], one[d]["d2_mse"], rtol=0.05)  # chunk-edge neighbourhoods only


def test_normals_from_the_file_are_used(tmp_path):
    from cloudsieve.io import open_writer

    a = _surface(2000, 5)
    tilt = np.column_stack([np.ones(len(a)), np.zeros(len(a)), np.ones(len(a))])  # not the surface's normals
    f8 = np.dtype("float64")
    dtypes = {"xyz": (f8, (3,)), "nx": (f8, ()), "ny": (f8, ()), "nz": (f8, ())}
    path = tmp_path / "with_normals.ply"
    with open_writer(path, header={}, dtypes=dtypes, format="ply", overwrite=True) as w:
        w.write({"xyz": a, "nx": tilt[:, 0].copy(), "ny": tilt[:, 1].copy(), "nz": tilt[:, 2].copy()})
    b = a[::3] + [0.0, 0.0, 0.01]
    rep = evaluate(str(path), b, surface=False)
    want = _oracle(a, b, rep["psnr"]["peak"], normals=tilt)
    assert rep["psnr"]["normals"] == "file" and rep["psnr"]["k_normals"] is None
    for key in ("forward", "backward", "symmetric"):
        assert rep["psnr"]["d2"][key] == pytest.approx(want["d2"][key], abs=0.01)


def test_pca_normals_equal_numpy_eigh():
    a = _surface(1500, 6) + np.random.default_rng(1).normal(scale=0.003, size=(1500, 3))
    got = pca_normals(a, a, 12)
    want = _normals_oracle(a, 12)
    assert_allclose(np.abs(np.einsum("ij,ij->i", got, want)), 1.0, atol=1e-9)


def test_psnr_formula_and_zero_mse():
    assert psnr(1.0, 1.0) == pytest.approx(10 * math.log10(3))
    assert psnr(0.0, 5.0) == math.inf


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), "big"])
def test_psnr_peak_must_be_positive(bad):
    with pytest.raises(InvalidParameterError, match=r"^psnr_peak must be a finite number > 0, got "):
        evaluate(np.zeros((3, 3)), np.zeros((1, 3)), surface=False, psnr_peak=bad)


def test_compare_table_has_the_psnr_and_chamfer_columns():
    from cloudsieve.evaluate import compare

    a = _surface(3000, 7)
    res = compare(a, methods=["random", "voxel"], ratio=0.25, surface=False, psnr_peak=2.0)
    assert "| D1 PSNR | D2 PSNR | Chamfer |" in res["markdown"]
    for row in res["rows"]:
        rep = res["reports"][row["method"]]
        assert row["d1_psnr"] == rep["psnr"]["d1"]["forward"] and row["d2_psnr"] == rep["psnr"]["d2"]["forward"]
        assert row["chamfer"] == rep["chamfer"]["value"] > 0
        assert f"| {row['d1_psnr']:.2f} | {row['d2_psnr']:.2f} |" in res["markdown"]
    assert res["psnr_peak"] == 2.0 and "peak 2 (given)" in res["markdown"]


def test_cli_evaluate_prints_and_writes_the_figures(tmp_path, capsys):
    import json

    from conftest import shared_file

    from cloudsieve.cli import main
    from cloudsieve.io import open_writer, read_cloud

    xyz, _ = read_cloud(shared_file("bun_zipper.ply"))
    simp = tmp_path / "s.ply"
    with open_writer(simp, header={}, dtypes={"xyz": (np.dtype("float64"), (3,))}, format="ply") as w:
        w.write({"xyz": xyz[::4]})
    out = tmp_path / "rep"
    assert main(["evaluate", str(shared_file("bun_zipper.ply")), str(simp), "--no-surface", "--no-progress",
                 "--psnr-peak", "0.5", "--report", str(out)]) == 0
    text = capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    assert rep["psnr"]["peak"] == 0.5 and rep["psnr"]["d1"]["backward"] is None  # a subset: no backward error
    assert f"D1 PSNR (dB)    : forward {rep['psnr']['d1']['forward']:.2f}  backward ∞" in text
    md = (out / "report.md").read_text()
    assert "## Field figures (MPEG pc_error D1/D2 PSNR, Chamfer)" in md and "| D2 |" in md


def test_sampled_psnr_is_near_the_exact_one():
    a = _surface(20_000, 8)
    b = a[::4] + np.random.default_rng(2).normal(scale=0.002, size=(5000, 3))
    exact = evaluate(a, b, surface=False)["psnr"]
    sampled = evaluate(a, b, surface=False, sample=5000)["psnr"]
    for metric in ("d1", "d2"):
        assert sampled[metric]["symmetric"] == pytest.approx(exact[metric]["symmetric"], abs=0.3)


def test_d2_on_a_sample_states_it_and_its_standard_error():
    a = _surface(30_000, 3)
    rng = np.random.default_rng(4)
    keep = a[rng.choice(len(a), 6000, replace=False)]
    moved = np.concatenate([keep, keep[:2000] + rng.normal(scale=0.005, size=(2000, 3))])
    exact = point_errors(a, moved, PointLevel(d2_sample=None))
    part = point_errors(a, moved, PointLevel(d2_sample=5000))
    assert "d2_sample" not in exact["forward"]
    for name in ("forward", "backward"):
        f = part[name]
        assert f["d2_sample"] == 5000 and f["d2_se"] > 0
        assert abs(f["d2_mse"] - exact[name]["d2_mse"]) < 5 * f["d2_se"]  # the sample's mean, within 5 standard errors
        assert f["mse"] == exact[name]["mse"]  # D1 stays exact
    rep = evaluate(a, moved, surface=False, d2_sample=5000)
    ps = rep["psnr"]
    assert ps["d2_sample"] == {"forward": 5000, "backward": 5000}
    mse = rep["point"]["forward"]["d2_mse"]
    assert ps["d2_se_db"]["forward"] == pytest.approx(10 / math.log(10) * rep["point"]["forward"]["d2_se"] / mse)
    small = evaluate(a, moved, surface=False, d2_sample=len(a))  # a sample as large as the cloud: every point
    assert "d2_sample" not in small["psnr"]
    assert small["point"]["forward"]["d2_mse"] == exact["forward"]["d2_mse"]
