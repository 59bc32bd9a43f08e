"""Issue 27, items 5 (evaluate) and 8: no noise a user (or a test run) did not ask for.

numba's threading layer is chosen by cloudsieve, so no TBB warning appears
even where open3d's older libtbb is loaded first; ``evaluate`` says a CRS
mismatch once, in one style; pytest itself starts without a warning.
"""

from __future__ import annotations

import os
import subprocess
import sys

import laspy
from laspy.vlrs.known import WktCoordinateSystemVlr

from conftest import ROOT, shared_file
from test_cli_help import cloudsieve

LAMBERT93 = ('PROJCS["RGF93 / Lambert-93",GEOGCS["RGF93",DATUM["Reseau_Geodesique_Francais_1993",'
             'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
             'PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["metre",1],AUTHORITY["EPSG","2154"]]')


def python(code: str, cwd) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-W", "always", "-c", code], capture_output=True, text=True, env=env,
                          cwd=cwd)


def test_no_tbb_warning_when_open3d_is_loaded_first(tmp_path):
    proc = python("import open3d\n"
                  "import numpy as np, numba, cloudsieve\n"
                  "pts = np.random.default_rng(0).random((20_000, 3))\n"
                  "print(len(cloudsieve.simplify_points(pts, rule='eliminate', ratio=0.5)), numba.threading_layer())",
                  tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    count, layer = proc.stdout.split()
    assert count == "10000" and layer in ("omp", "workqueue")


def test_evaluate_says_a_crs_mismatch_once(tmp_path):
    las = laspy.read(shared_file("simple.las"))
    las.header.vlrs.append(WktCoordinateSystemVlr(LAMBERT93))
    other = tmp_path / "lambert93.las"
    las.write(other)
    proc = cloudsieve(["evaluate", shared_file("simple.copc.laz"), other, "--no-strict", "--no-surface",
                       "--no-progress"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("WARNING cloudsieve.evaluate.evaluation: different CRS: "), lines


def test_pytest_starts_without_a_warning(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "tests/test_errors.py"],
                          capture_output=True, text=True, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "warnings summary" not in proc.stdout and "Warning" not in proc.stdout, proc.stdout


def test_a_local_cluster_beside_port_8787_says_nothing():
    import socket
    import warnings

    from cloudsieve.engine.runner import Runner

    taken = socket.socket()
    try:
        try:
            taken.bind(("0.0.0.0", 8787))
            taken.listen()
        except OSError:  # already in use (another cluster): the case itself
            pass
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            runner = Runner(None, 1, memory_limit="1GB")  # a LocalCluster of 1 worker process
            runner.close()
    finally:
        taken.close()
    assert [str(w.message) for w in got if "8787" in str(w.message)] == []
