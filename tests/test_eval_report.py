"""evaluate(): report files, CLI, bad input (CRS, units, empty, not a subset)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_file
from numpy.testing import assert_allclose
from scipy.spatial import cKDTree

from cloudsieve.cli import main
from cloudsieve.errors import EmptyInputError, IncompatibleCloudsError, IncompatibleCloudsWarning, NotASubsetError
from cloudsieve.evaluate import check_compatible, evaluate
from cloudsieve.io import open_writer, read_cloud


def _write_ply(path, xyz):
    with open_writer(path, header={}, dtypes={"xyz": (np.dtype("float64"), (3,))}, format="ply") as w:
        w.write({"xyz": xyz})
    return str(path)


@pytest.fixture(scope="module")
def bunny():
    xyz, _ = read_cloud(shared_file("bun_zipper.ply"))
    return xyz


def test_report_files_exist_and_parse(tmp_path, bunny):
    orig = bunny
    simp = orig[np.sort(np.random.default_rng(0).choice(len(orig), len(orig) // 3, replace=False))]
    o, s = _write_ply(tmp_path / "o.ply", orig), _write_ply(tmp_path / "s.ply", simp)
    out = tmp_path / "rep"
    assert main(["evaluate", o, s, "--report", str(out), "--tile-points", "12000", "--tiles", "2", "--subset",
                 "--no-progress"]) == 0
    rep = json.loads((out / "report.json").read_text())
    p = rep["point"]
    for name in ("forward", "backward"):
        for key in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct"):
            assert isinstance(p[name][key], float)
    assert p["backward"]["max"] == 0.0 and p["subset"] is True
    f = cKDTree(simp).query(orig)[0]
    assert_allclose(p["forward"]["mean"], f.mean(), rtol=1e-12)
    assert p["forward"]["max_pct"] == pytest.approx(100 * f.max() / rep["diagonal"])
    sf = rep["surface"]
    assert len(sf["tiles"]) == 2
    for key in ("mean", "rms", "max", "mean_pct", "rms_pct", "max_pct", "compact_share", "vertices", "faces"):
        assert sf[key] is not None
    md = (out / "report.md").read_text()
    assert "| original → simplified |" in md and "compactness ≥ 0.6" in md
    per_face = sf["original"]["border_edges"] / sf["original"]["faces"]
    assert 0 < per_face < 0.05 and f"| {per_face:.3f} |" in md  # bun_zipper: the tiles' rims, few holes, no note
    assert "border edges per face" in md and "whatever the sampling" not in md
    for png in ("compactness.png", "point_errors.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    xyz, attrs = read_cloud(out / "errors.ply")
    assert len(xyz) == len(orig)
    assert_allclose(attrs["error"], cKDTree(simp).query(xyz)[0], rtol=1e-6)
    zero = attrs["error"] == 0
    assert np.all(attrs["red"][zero] > 100) and np.all(attrs["blue"][zero] == 0)  # red = 0
    top = np.argmax(attrs["error"])
    assert attrs["blue"][top] > 100 and attrs["red"][top] == 0  # blue = max


def test_evaluate_sampled_reports_ci(bunny):
    simp = bunny[::2]
    r = evaluate(bunny, simp, sample=5000, surface=False, seed=1)
    assert r["point"]["mode"] == "sampled"
    ci = r["point"]["forward"]["ci"]
    assert ci["mean"][0] <= r["point"]["forward"]["mean"] <= ci["mean"][1]
    assert "surface" not in r


def test_empty_simplified_file(tmp_path, bunny):
    o = _write_ply(tmp_path / "o.ply", bunny)
    empty = _write_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    with pytest.raises(EmptyInputError, match="simplified cloud is empty"):
        evaluate(o, empty)
    assert main(["evaluate", o, empty, "--no-progress"]) == 2


def test_not_a_subset_when_claimed(bunny):
    simp = bunny[::4] + [1e-4, 0, 0]
    with pytest.raises(NotASubsetError, match=r"simplified points are not points of the original"):
        evaluate(bunny, simp, subset=True, surface=False)
    r = evaluate(bunny, simp, surface=False)  # not claimed: measured
    assert r["point"]["backward"]["max"] == pytest.approx(1e-4, rel=1e-6)
    assert r["point"]["subset"] is False


def test_units_mismatch_flagged(bunny):
    with pytest.raises(IncompatibleCloudsError, match="different units or position"):
        evaluate(bunny, bunny[::3] * 1000.0, surface=False)  # metres vs millimetres
    with pytest.warns(UserWarning, match="different units"):
        r = evaluate(bunny, bunny[::3] * 1000.0, surface=False, strict=False)
    assert any("different units" in w for w in r["warnings"])


def test_crs_mismatch_flagged(tmp_path):
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    src = shared_file("simple.copc.laz")  # NAD83 / Oregon LCC
    las = laspy.read(shared_file("simple.las"))  # same points, no CRS VLR
    other = tmp_path / "lambert93.las"
    las.header.vlrs.append(WktCoordinateSystemVlr(
        'PROJCS["RGF93 / Lambert-93",GEOGCS["RGF93",DATUM["Reseau_Geodesique_Francais_1993",'
        'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
        'PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["metre",1],AUTHORITY["EPSG","2154"]]'))
    las.write(other)
    with pytest.raises(IncompatibleCloudsError, match="different CRS"):
        evaluate(src, other, surface=False)
    assert main(["evaluate", str(src), str(other), "--no-surface", "--no-progress"]) == 2
    with pytest.warns(IncompatibleCloudsWarning, match="different CRS"):
        r = evaluate(src, other, surface=False, strict=False)
    assert any("different CRS" in w for w in r["warnings"])
    # no CRS on one side: a warning only
    r = evaluate(src, shared_file("simple.las"), surface=False)
    assert any("only the" in w and "has a CRS" in w for w in r["warnings"])


def test_check_compatible_headers():
    pts = np.zeros((3, 3))
    b = np.array([[0, 0, 0], [1, 1, 1]], float)
    assert check_compatible({"crs": {"epsg": "2154"}}, {"crs": {"epsg": 2154}}, b, pts) == []
    with pytest.raises(IncompatibleCloudsError, match="original has epsg '2154', simplified has epsg '2903'"):
        check_compatible({"crs": {"epsg": "2154"}}, {"crs": {"epsg": "2903"}}, b, pts)
    # an EPSG code on one side, only WKT on the other: compared by WKT
    wkt = 'PROJCS["X",AUTHORITY["EPSG","2154"]]'
    assert check_compatible({"crs": {"epsg": 2154, "wkt": wkt}}, {"crs": {"wkt": wkt}}, b, pts) == []


def test_report_notes_the_holes_of_the_original_mesh(tmp_path, capsys):
    """vegetation_1_3's ball-pivoting mesh is about half border edges: the CLI and report.md say so."""
    from cloudsieve.evaluate.report import HOLEY, border_per_face

    path = shared_file("vegetation_1_3.las")
    xyz, _ = read_cloud(path)
    s = _write_ply(tmp_path / "s.ply", xyz[::2])
    assert main(["evaluate", str(path), s, "--subset", "--no-progress", "--report", str(tmp_path / "rep")]) == 0
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    o, m = rep["surface"]["original"], rep["surface"]["simplified"]
    assert o["border_edges"] > HOLEY * o["faces"]
    assert (f"border edges    : original {border_per_face(o)} per face, simplified {border_per_face(m)} (holes of "
            "the ball-pivoting meshes)") in capsys.readouterr().out
    md = (tmp_path / "rep" / "report.md").read_text()
    assert f"The original's mesh has {border_per_face(o)} border edges per face" in md
    assert "whatever the sampling" in md
