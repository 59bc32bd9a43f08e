"""Issue 48, item 8: messages that named the wrong thing (Ctrl-C's hint, a CRS, a file, duplicates, a path)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cloudsieve.engine.pause import PAUSE_ENV
from cloudsieve.synthetic import write_scene_laz


def _wait_for(driver: subprocess.Popen, marker: Path) -> None:
    """Until the run has stopped at its pause point (its process id in *marker*); 600 s only guard a hang."""
    deadline = time.monotonic() + 600
    while driver.poll() is None and time.monotonic() < deadline:
        if marker.exists() and marker.read_text().strip():
            return
        time.sleep(0.05)
    raise AssertionError(f"the run did not reach its pause (exit status {driver.returncode})")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SIGINT to a process group, Linux semantics")
def test_ctrl_c_of_a_tiles_run_into_a_folder_with_a_slash_names_its_kept_work_store(tmp_path: Path):
    """DST ``out/``: the work store is out.cloudsieve.zarr beside the folder, and the hint says it is kept."""
    src = write_scene_laz(str(tmp_path / "scene.laz"), 20_000, seed=1)
    marker = tmp_path / "paused"
    cmd = [sys.executable, "-m", "cloudsieve", "simplify", src, str(tmp_path / "out") + "/", "--ratio", "0.5",
           "--tile-size", "100", "--scheduler", "sync", "--no-progress"]
    driver = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                              env={**os.environ, PAUSE_ENV: f"driver:cells: apply={marker}"})
    try:
        _wait_for(driver, marker)
        os.kill(driver.pid, signal.SIGINT)
        _, err = driver.communicate(timeout=120)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode == 130, err
    assert (tmp_path / "out.cloudsieve.zarr").is_dir()
    assert err.strip().splitlines()[-1] == ("cloudsieve simplify: interrupted; the work store is kept: run the same "
                                            "command again (or add --resume) to continue")
    done = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "index.vpc").exists() and not (tmp_path / "out.cloudsieve.zarr").exists()


def _run(argv: list[str], capsys) -> tuple[int, str]:
    from cloudsieve.cli import main

    rc = main(argv)
    return rc, capsys.readouterr().err


def test_a_crs_given_by_geotiff_keys_alone_is_named_when_files_disagree(tmp_path, capsys):
    """Megaplot.laz's CRS is GeoTIFF keys only (EPSG 26917, no WKT): the message names it, not "none"."""
    from conftest import shared_file

    veg, mega = shared_file("vegetation_1_3.las"), shared_file("Megaplot.laz")  # both point format 1
    lst = tmp_path / "files.lst"
    lst.write_text(f"{veg}\n{mega}\n")
    rc, err = _run(["simplify", str(lst), str(tmp_path / "o.laz"), "--ratio", "0.5", "--no-progress"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve simplify: error: {mega}: its CRS (EPSG:26917) differs from that of {veg} (none): the "
                   "files of one cloud must share their CRS; reproject them first\n")
    assert not (tmp_path / "o.laz").exists()


def test_geotiff_keys_without_an_epsg_code_are_named_by_their_citation(tmp_path):
    """autzen_trim's keys say user-defined (32767): without its WKT record the citation names the CRS."""
    import laspy
    from conftest import shared_file

    from cloudsieve.errors import MismatchedInputsError
    from cloudsieve.io.las_plan import plan_las

    las = laspy.read(shared_file("autzen_trim.las"))
    las.header.vlrs = [v for v in las.header.vlrs if v.record_id != 2112]  # the WKT (and liblas's copy) dropped
    las.write(tmp_path / "keys.las")
    plain = laspy.read(shared_file("autzen_trim.las"))
    plain.header.vlrs = []
    plain.write(tmp_path / "plain.las")
    with pytest.raises(MismatchedInputsError) as e:
        plan_las([str(tmp_path / "plain.las"), str(tmp_path / "keys.las")])
    assert str(e.value) == (
        f"{tmp_path / 'keys.las'}: its CRS (GeoTIFF keys without an EPSG code: \"NAD_1983_HARN_Lambert_Conformal_Conic\") "
        f"differs from that of {tmp_path / 'plain.las'} (none): the files of one cloud must share their CRS; "
        "reproject them first")


def test_the_finest_scale_is_credited_to_the_file_that_has_it(tmp_path):
    """a.las (0.01, first: the cloud's offset), b.las (0.001: the finest), c.las off the fine grid: each named."""
    import laspy
    from conftest import shared_file

    from cloudsieve.errors import MismatchedInputsError
    from cloudsieve.io.las_plan import plan_las

    src = shared_file("simple.las")
    las = laspy.read(src)
    las.write(tmp_path / "a.las")
    fine = laspy.read(src)
    fine.change_scaling(scales=[0.001, 0.01, 0.01])
    fine.write(tmp_path / "b.las")
    off = laspy.read(src)
    off.change_scaling(offsets=las.header.offsets + [0.0005, 0, 0])
    off.write(tmp_path / "c.las")
    paths = [str(tmp_path / n) for n in ("a.las", "b.las", "c.las")]
    with pytest.raises(MismatchedInputsError) as e:
        plan_las(paths)
    o = las.header.offsets[0]
    assert str(e.value) == (
        f"{paths[2]}: the x offset {o + 0.0005:g} is 0.5 steps of the cloud's x scale 0.001 (the finest, from "
        f"{paths[1]}) from the cloud's x offset {o:g} (from {paths[0]}), not a whole number: its records are not "
        "exactly representable; re-quantise the files to one scale and offset first")
    plan = plan_las(paths[:2])  # representable: b's scale, a's offset
    assert plan.scale.tolist() == [0.001, 0.01, 0.01] and plan.offset.tolist() == las.header.offsets.tolist()


def test_a_count_above_the_input_names_the_duplicates_it_keeps_once(tmp_path, caplog):
    """300 points, one an exact copy: --count 500 keeps 299, and the warning says why one fewer than 300."""
    import logging

    import numpy as np

    import cloudsieve

    a = np.random.default_rng(0).random((300, 3))
    a[7] = a[3]
    src = tmp_path / "dup.xyz"
    np.savetxt(src, a, fmt="%.6f")
    with caplog.at_level(logging.WARNING, logger="cloudsieve"):
        summary = cloudsieve.simplify(src, tmp_path / "o.las", count=500, scheduler="sync")
    assert (summary.kept, summary.duplicates) == (299, 1)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [f"{src}: asked to keep 500 points, kept 299: the input holds only 300 points, 1 of them exact "
                        "duplicates, kept once (keep_duplicates keeps them)"]
    # keep_duplicates: every point kept, the input's size alone explains the count
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="cloudsieve"):
        kept = cloudsieve.simplify(src, tmp_path / "k.las", count=500, keep_duplicates=True, scheduler="sync").kept
    assert kept == 300
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING] == [
        f"{src}: asked to keep 500 points, kept 300: the input holds only 300 points"]


def test_evaluate_names_its_report_once_joined_when_the_folder_ends_in_a_slash(tmp_path, capsys):
    import numpy as np

    a = np.random.default_rng(1).random((400, 3))
    np.savetxt(tmp_path / "a.xyz", a, fmt="%.6f")
    np.savetxt(tmp_path / "b.xyz", a[::2], fmt="%.6f")
    from cloudsieve.cli import main

    rc = main(["evaluate", str(tmp_path / "a.xyz"), str(tmp_path / "b.xyz"), "--report", str(tmp_path / "rep1") + "/",
               "--no-surface", "--no-progress"])
    out = capsys.readouterr().out
    assert rc == 0
    assert out.splitlines()[-1] == f"report: {tmp_path / 'rep1' / 'report.html'} (and report.md, report.json)"
    assert (tmp_path / "rep1" / "report.html").is_file()
