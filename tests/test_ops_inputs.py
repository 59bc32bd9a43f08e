"""Issue 13, items 5, 6 and 8: advice that works, ``run --check`` that checks, the smaller ones.

Each test asserts what a user sees: the exit code, the exact message, and the
files left (nothing, on a failure). Commands run in this process through
``cloudsieve.cli.main``; the few checks of raw stderr (log lines) run the
installed entry point in a subprocess.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.errors import DestinationExistsError, IncompatibleCloudsError, InvalidPointsError, PipelineError
from cloudsieve.io import read_cloud
from cloudsieve.pipeline import load_pipeline
from cloudsieve.store import export, ingest
from conftest import ROOT, shared_file


def run(argv, capsys):
    """(exit code, stdout, stderr) of ``cloudsieve ARGV`` in this process."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def run_command(argv, cwd):
    """(exit code, stderr) of ``python -m cloudsieve ARGV`` in a subprocess: the raw stderr, log lines included."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "cloudsieve", *map(str, argv)], capture_output=True, text=True,
                          env=env, cwd=cwd)
    return proc.returncode, proc.stderr


def listing(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def write_nan_xyz(path, n=300):
    """*n* points on a noisy plane, points 5 and 77 with a NaN / an infinite coordinate."""
    xyz = np.random.default_rng(0).random((n, 3))
    xyz[5, 0] = np.nan
    xyz[77, 1] = np.inf
    np.savetxt(path, xyz, fmt="%.6f")
    return path


def nan_message(path, advice):
    return f"{path}: 2 of 300 points have NaN or infinite coordinates (first: point 5); pass {advice} to drop them"


# ------------------------------------------------------------------ item 5: the advice works where it is given


def test_nan_advice_is_drop_invalid_for_simplify_evaluate_compare(tmp_path, capsys):
    src = write_nan_xyz(tmp_path / "nan.xyz")
    good = tmp_path / "good.xyz"
    np.savetxt(good, np.random.default_rng(1).random((100, 3)), fmt="%.6f")
    before = listing(tmp_path)
    commands = {
        "simplify": ["simplify", src, tmp_path / "out.las", "--ratio", "0.5", "--scheduler", "sync", "--no-progress"],
        "evaluate": ["evaluate", src, good, "--no-surface", "--no-progress"],
        "compare": ["compare", src, "--methods", "random,voxel", "--ratio", "0.5", "--no-surface", "--no-progress"],
    }
    for command, argv in commands.items():
        rc, _, err = run(argv, capsys)
        assert rc == 2
        assert err == f"cloudsieve {command}: error: {nan_message(src, '--drop-invalid')}\n"
        assert listing(tmp_path) == before  # no output, no work store
    # the advice works
    rc, _, _ = run([*commands["simplify"], "--drop-invalid"], capsys)
    assert rc == 0 and len(read_cloud(tmp_path / "out.las")[0]) > 0
    rc, out, _ = run([*commands["evaluate"], "--drop-invalid"], capsys)
    assert rc == 0 and out.startswith("original 298 points, simplified 100")
    rc, out, _ = run([*commands["compare"], "--drop-invalid"], capsys)
    assert rc == 0 and "| random | 149 |" in out


def test_nan_advice_in_the_api_is_drop_invalid_true(tmp_path):
    src = write_nan_xyz(tmp_path / "nan.xyz")
    calls = [
        lambda **kw: cloudsieve.simplify(src, tmp_path / "out.las", ratio=0.5, scheduler="sync", **kw),
        lambda **kw: cloudsieve.evaluate(src, src, surface=False, **kw),
        lambda **kw: cloudsieve.compare(src, methods=["random"], ratio=0.5, surface=False, **kw),
    ]
    for call in calls:
        with pytest.raises(InvalidPointsError) as info:
            call()
        assert str(info.value) == nan_message(src, "drop_invalid=True")
        assert info.value.advice == {"drop_invalid": True}
    assert listing(tmp_path) == ["nan.xyz"]
    summary = cloudsieve.simplify(src, tmp_path / "out.las", ratio=0.5, scheduler="sync", drop_invalid=True)
    assert summary.points_in == 298


def test_nan_advice_in_a_pipeline_is_the_reader_key(tmp_path, capsys):
    src = write_nan_xyz(tmp_path / "nan.xyz")
    out = tmp_path / "out.las"
    doc = {"scheduler": "sync", "pipeline": [
        {"type": "readers.text", "filename": str(src)}, {"type": "filters.entropy", "ratio": 0.5},
        {"type": "writers.las", "filename": str(out)}]}
    (tmp_path / "p.json").write_text(json.dumps(doc))
    rc, _, err = run(["run", tmp_path / "p.json"], capsys)
    assert rc == 2
    advice = '"drop_invalid": true in the readers.text stage (or --set readers.text.drop_invalid=true)'
    assert err == f"cloudsieve run: error: {nan_message(src, advice)}\n"
    assert listing(tmp_path) == ["nan.xyz", "p.json"]
    rc, _, _ = run(["run", tmp_path / "p.json", "--set", "readers.text.drop_invalid=true"], capsys)
    assert rc == 0 and out.exists()


def test_pipeline_reader_takes_drop_invalid(tmp_path):
    """drop_invalid is the reader's option: checked as the API checks it, refused in the other stages."""
    reader = {"type": "readers.las", "filename": "a.las"}
    rest = [{"type": "filters.entropy", "ratio": 0.5}, {"type": "writers.las", "filename": "b.las"}]
    assert load_pipeline({"pipeline": [{**reader, "drop_invalid": True}, *rest]}).reader["drop_invalid"] is True
    with pytest.raises(PipelineError) as info:
        load_pipeline({"pipeline": [{**reader, "drop_invalid": "yes"}, *rest]})
    assert str(info.value) == "<pipeline>: stage 1 (readers.las): drop_invalid must be true or false, got 'yes'"
    with pytest.raises(PipelineError, match=r"stage 2 \(filters.entropy\): unknown option\(s\) \['drop_invalid'\]"):
        load_pipeline({"pipeline": [reader, {"type": "filters.entropy", "ratio": 0.5, "drop_invalid": True}, rest[1]]})


def test_overwrite_advice_api_cli_and_run(tmp_path, capsys):
    src = shared_file("simple.las")
    dst = tmp_path / "out.las"
    dst.write_bytes(b"precious")
    with pytest.raises(DestinationExistsError) as info:
        cloudsieve.simplify(src, dst, ratio=0.5, scheduler="sync")
    assert str(info.value) == f"{dst} exists; pass overwrite=True to replace it"
    rc, _, err = run(["simplify", src, dst, "--ratio", "0.5", "--scheduler", "sync", "--no-progress"], capsys)
    assert (rc, err) == (2, f"cloudsieve simplify: error: {dst} exists; pass --overwrite to replace it\n")
    store = tmp_path / "s.zarr"
    store.mkdir()
    rc, _, err = run(["ingest", src, store, "--no-progress"], capsys)
    assert (rc, err) == (2, f"cloudsieve ingest: error: {store} exists (a folder); pass --overwrite to replace it\n")
    doc = {"scheduler": "sync", "pipeline": [str(src), {"type": "filters.entropy", "ratio": 0.5},
                                             {"type": "writers.las", "filename": str(dst)}]}
    (tmp_path / "p.json").write_text(json.dumps(doc))
    rc, _, err = run(["run", tmp_path / "p.json"], capsys)
    assert rc == 2
    assert err == (f'cloudsieve run: error: {dst} exists; pass "overwrite": true in the writers.las stage '
                   f"(or --set writers.las.overwrite=true) to replace it\n")
    assert dst.read_bytes() == b"precious" and listing(tmp_path) == ["out.las", "p.json", "s.zarr"]
    rc, _, _ = run(["run", tmp_path / "p.json", "--set", "writers.las.overwrite=true"], capsys)
    assert rc == 0 and laspy.read(dst).header.point_count > 0


def test_destination_is_source_never_suggests_overwrite(tmp_path, capsys):
    src = tmp_path / "scan.las"
    src.write_bytes(shared_file("simple.las").read_bytes())
    for extra in ([], ["--overwrite"]):
        rc, _, err = run(["simplify", src, src, "--ratio", "0.5", "--scheduler", "sync", "--no-progress", *extra],
                         capsys)
        assert (rc, err) == (2, f"cloudsieve simplify: error: {src} is the source: cloudsieve never overwrites its input\n")
    assert listing(tmp_path) == ["scan.las"]
    assert src.read_bytes() == shared_file("simple.las").read_bytes()


def test_resume_mismatch_and_strict_advice_in_cli_words(tmp_path, capsys):
    src, out, store = shared_file("simple.las"), tmp_path / "out.las", tmp_path / "work.zarr"
    base = ["simplify", src, out, "--rule", "iterative", "--store", store, "--scheduler", "sync", "--no-progress"]
    assert run(base, capsys)[0] == 0
    out.unlink()  # the work store stays (an explicit --store is kept)
    rc, _, err = run([*base, "--threshold", "0.002"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve simplify: error: store {store} holds a run with other parameters threshold: "
                   f"stored 0.001, asked 0.002; pass --overwrite to discard it\n")
    # different units: the advice is --no-strict (the API says strict=False)
    xyz, _ = read_cloud(src)
    feet = tmp_path / "feet.xyz"
    np.savetxt(feet, xyz[::2] * 1000.0, fmt="%.3f")
    rc, _, err = run(["evaluate", src, feet, "--no-surface", "--no-progress"], capsys)
    assert rc == 2 and err.endswith("(pass --no-strict to compare anyway)\n")
    with pytest.raises(IncompatibleCloudsError, match=r"\(pass strict=False to compare anyway\)$"):
        cloudsieve.evaluate(src, feet, surface=False)


# ------------------------------------------------------------------ item 6: run --check fails on what will fail


def test_check_fails_on_a_missing_input(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    pipeline = ROOT / "pipelines" / "simplify.json"
    rc, out, err = run(["run", pipeline, "--check"], capsys)
    assert (rc, out) == (2, "")
    assert err == f"cloudsieve run: error: {pipeline}: stage 1 (readers.las): input.laz: no such file\n"
    assert listing(tmp_path) == []


def test_check_fails_on_an_unset_variable(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("CLOUDSIEVE_DATA", raising=False)
    pipeline = ROOT / "pipelines" / "paper-maxplanck.json"
    rc, _, err = run(["run", pipeline, "--check"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve run: error: {pipeline}: stage 1 (readers.ply): filename "
                   "'${CLOUDSIEVE_DATA}/maxplanck.ply' uses the environment variable CLOUDSIEVE_DATA, which is not set\n")
    monkeypatch.setenv("CLOUDSIEVE_DATA", str(shared_file("maxplanck.ply").parent))
    rc, out, _ = run(["run", pipeline, "--check"], capsys)
    assert rc == 0 and out.startswith(f"{pipeline}: valid; 1 input(s)")
    assert listing(tmp_path) == []


def test_check_names_an_unknown_reader_key_and_the_accepted_ones(tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"pipeline": [{"type": "readers.las", "filenme": "scan.las"},
                                             {"type": "filters.entropy", "ratio": 0.5},
                                             {"type": "writers.las", "filename": "out.las"}]}))
    rc, _, err = run(["run", path, "--check"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve run: error: {path}: stage 1 (readers.las): unknown option(s) ['filenme']; "
                   "accepted: ['drop_invalid', 'filename', 'merge']\n")
    path.write_text(json.dumps({"pipeline": [{"type": "readers.las", "filename": str(shared_file("bun_zipper.ply"))},
                                             {"type": "filters.entropy", "ratio": 0.5},
                                             {"type": "writers.las", "filename": "out.las"}]}))
    rc, _, err = run(["run", path, "--check"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve run: error: {path}: stage 1 (readers.las) cannot read "
                   f"{shared_file('bun_zipper.ply')}: its extension says ply\n")
    assert listing(tmp_path) == ["p.json"]


# ------------------------------------------------------------------ item 8: the smaller ones


@pytest.fixture
def umask():
    """Set the process umask for a test (restored after it)."""
    old = os.umask(0o022)
    yield lambda mask: os.umask(mask)
    os.umask(old)


def mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_outputs_get_the_umask_mode(tmp_path, umask):
    store = ingest(shared_file("simple.las"), tmp_path / "s.zarr")
    assert mode(store.path) == 0o755 and mode(tmp_path / "s.zarr" / "zarr.json") == 0o644
    for ext in (".las", ".laz", ".ply", ".xyz"):
        export(store, tmp_path / f"out{ext}")
        assert mode(tmp_path / f"out{ext}") == 0o644, ext
    cloudsieve.simplify(store.path, tmp_path / "small.laz", ratio=0.5, scheduler="sync")
    assert mode(tmp_path / "small.laz") == 0o644
    umask(0o027)
    export(store, tmp_path / "private.las")
    assert mode(tmp_path / "private.las") == 0o640
    assert mode(ingest(shared_file("simple.laz"), tmp_path / "p.zarr").path) == 0o750


def test_binary_ply_float_xyz_written_back_as_float(tmp_path):
    xyz, attrs = read_cloud(shared_file("bun_zipper.ply"))
    body = np.empty(500, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    for i, axis in enumerate("xyz"):
        body[axis] = xyz[:500, i]
    body["intensity"] = attrs["intensity"][:500]
    src = tmp_path / "bunny.ply"
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 500\nproperty float x\nproperty float y\n"
              "property float z\nproperty float intensity\nend_header\n")
    src.write_bytes(header.encode() + body.tobytes())
    export(ingest(src, tmp_path / "s.zarr"), tmp_path / "out.ply")
    text = (tmp_path / "out.ply").read_bytes().split(b"end_header")[0].decode()
    assert "property float x\nproperty float y\nproperty float z\nproperty float intensity" in text
    np.testing.assert_array_equal(read_cloud(tmp_path / "out.ply")[0], read_cloud(src)[0])
    assert (tmp_path / "out.ply").stat().st_size < src.stat().st_size + 200  # not widened to double
    # an ASCII body is parsed to double and written as double: no digit lost
    export(ingest(shared_file("bun_zipper.ply"), tmp_path / "a.zarr"), tmp_path / "ascii.ply")
    assert b"property double x" in (tmp_path / "ascii.ply").read_bytes()[:400]


def test_truncated_laz_one_clean_line_naming_the_point(tmp_path):
    cut = tmp_path / "cut.laz"
    cut.write_bytes(shared_file("simple.laz").read_bytes()[:8000])
    rc, err = run_command(["ingest", cut, tmp_path / "s.zarr", "--no-progress"], tmp_path)
    assert rc == 2
    assert err == (f"cloudsieve ingest: error: {cut}: cannot decode point 434 of 1065 (points 0 to 433 decode; "
                   "IoError: failed to fill whole buffer); truncated or corrupt\n")
    assert listing(tmp_path) == ["cut.laz"]


def test_copc_records_dropped_with_a_warning_line(tmp_path):
    store = ingest(shared_file("simple.copc.laz"), tmp_path / "s.zarr")
    out = tmp_path / "out.laz"
    rc, err = run_command(["export", store.path, out, "--no-progress"], tmp_path)  # no -v
    assert rc == 0
    lines = err.splitlines()
    assert lines[0] == (f"WARNING cloudsieve.io.las_header: {out}: dropping COPC record (user_id 'copc', record_id 1): "
                        "it describes the source's octree layout and is not valid in a re-ordered or plain LAS/LAZ file")
    assert lines[1].startswith(f"WARNING cloudsieve.io.las_header: {out}: dropping COPC record (user_id 'copc', "
                               "record_id 1000)")


def test_info_prints_bounds_with_every_digit(capsys):
    rc, out, _ = run(["info", shared_file("1_4_w_evlr.laz")], capsys)
    assert rc == 0
    assert "  x           1694038.445637 .. 1694539.677014\n  y           1816492.706270 .. 1816497.976262\n" in out
    rc, out, _ = run(["info", shared_file("simple.las")], capsys)
    assert "  y           848899.70 .. 853535.43\n" in out  # the scale's 2 decimals
    rc, out, _ = run(["info", shared_file("bun_zipper.ply")], capsys)
    assert "  x           -0.0946899 .. 0.0610091\n" in out


def test_simplify_json_store_is_null_when_removed(tmp_path, capsys):
    src = shared_file("simple.las")
    rc, out, _ = run(["simplify", src, tmp_path / "a.las", "--ratio", "0.5", "--scheduler", "sync", "--no-progress",
                      "--json"], capsys)
    assert rc == 0 and json.loads(out)["store"] is None
    kept = tmp_path / "kept.zarr"
    rc, out, _ = run(["simplify", src, tmp_path / "b.las", "--ratio", "0.5", "--store", kept, "--scheduler", "sync",
                      "--no-progress", "--json"], capsys)
    assert rc == 0 and json.loads(out)["store"] == str(kept)


def test_demo_refuses_a_non_empty_folder_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    argv = ["demo", "--points", "3000", "--out", out, "--scheduler", "sync"]
    rc, stdout, err = run(argv, capsys)
    assert (rc, stdout) == (2, "")
    assert err == (f"cloudsieve demo: error: {out} exists and is not empty (1 entries); pass --overwrite to write "
                   "the demo into it anyway (its demo files are replaced, others kept), or choose another --out\n")
    assert listing(tmp_path) == ["demo", "demo/notes.txt"]
    rc, stdout, _ = run([*argv, "--overwrite"], capsys)
    assert rc == 0 and "kept 1,500 of 3,000 points" in stdout
    assert (out / "notes.txt").read_text() == "mine" and (out / "scene-simplified.laz").exists()


def test_a_missed_count_is_said(tmp_path, caplog):
    """Issue 13, item 4: a ratio or count that cannot be met is a warning naming requested and delivered counts."""
    import logging

    from cloudsieve import simplify
    from conftest import shared_file

    src = shared_file("simple.las")
    with caplog.at_level(logging.WARNING, logger="cloudsieve.engine.simplify"):
        s = simplify(src, tmp_path / "o.las", rule="target", count=5000, scheduler="sync")
    assert s.kept == 1065
    assert f"{src}: asked to keep 5,000 points, kept 1,065: the input holds only 1,065 points" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="cloudsieve.engine.simplify"):
        s = simplify(src, tmp_path / "p.las", rule="target", ratio=0.5, scheduler="sync")
    if s.kept != 532:  # 0.5 * 1065 rounds to 532: said whenever missed
        assert f"asked to keep 532 points, kept {s.kept:,}" in caplog.text
    else:
        assert "asked to keep" not in caplog.text
