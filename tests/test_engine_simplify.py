"""End to end: cloudsieve.engine.simplify on real LAZ files and generated clouds,
real zarr stores on disk, dask's local schedulers and a real dask.distributed
LocalCluster of worker processes on loopback.

Sizes are small (a few thousand points per cell) so that the whole file runs
in a few minutes on 2 cores; KM and the threshold rule keep the core fast where
the test is about the engine, not the method.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import laspy
import numpy as np
import pytest
import zarr
from conftest import shared_file
from engine_data import plane, write_laz
from resume_data import kill_at

from cloudsieve.engine import halo as H
from cloudsieve.engine import partition as P
from cloudsieve.engine import runs as R
from cloudsieve.engine import workstore
from cloudsieve.cli import main
from cloudsieve.store import ingest
from cloudsieve.engine import simplify
from cloudsieve.errors import InvalidParameterError, ResumeMismatchError
from cloudsieve.store import PointStore
from cloudsieve.engine.pause import PAUSE_ENV
from cloudsieve.engine.runner import NO_HTTP_PORT

FAST = dict(method="km", rule="threshold", cluster_size=200, seed=7)


def read_xyz(path) -> np.ndarray:
    las = laspy.read(str(path))
    return np.c_[las.x, las.y, las.z]


def digest(path) -> bytes:
    return Path(path).read_bytes()


@pytest.fixture(scope="module")
def cluster2():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      scheduler_kwargs=NO_HTTP_PORT) as c:
        with Client(c) as client:
            yield client


@pytest.fixture(scope="module")
def real_laz():
    return shared_file("append-bug.laz")


@pytest.fixture(scope="module")
def reference(real_laz, tmp_path_factory):
    """The output of the synchronous scheduler, the reference for every other run."""
    d = tmp_path_factory.mktemp("ref")
    out = d / "ref.laz"
    s = simplify(real_laz, out, scheduler="sync", cell_size=6_000, chunk_size=10_000, **FAST)
    return out, s


# ----------------------------------------------------------------- determinism


@pytest.mark.parametrize(
    "scheduler, workers",
    [("threads", 1), ("threads", 2), ("processes", 2), ("processes", 1)],
)
def test_same_bytes_on_every_local_scheduler(reference, real_laz, tmp_path, scheduler, workers):
    ref, ref_summary = reference
    out = tmp_path / "out.laz"
    s = simplify(real_laz, out, scheduler=scheduler, workers=workers, cell_size=6_000, chunk_size=10_000, **FAST)
    assert digest(out) == digest(ref)
    assert (s.kept, s.points_in, s.cells) == (ref_summary.kept, ref_summary.points_in, ref_summary.cells)
    assert 0 < s.kept < s.points_in


def test_same_bytes_on_a_local_cluster_with_1_and_2_workers(reference, real_laz, tmp_path, cluster2):
    from distributed import Client, LocalCluster

    ref, _ = reference
    out2 = tmp_path / "two.laz"
    simplify(real_laz, out2, client=cluster2, cell_size=6_000, chunk_size=10_000, **FAST)
    assert digest(out2) == digest(ref)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      scheduler_kwargs=NO_HTTP_PORT) as c:
        with Client(c) as client:
            out1 = tmp_path / "one.laz"
            simplify(real_laz, out1, client=client, cell_size=6_000, chunk_size=10_000, **FAST)
    assert digest(out1) == digest(ref)


def test_scheduler_address_and_fcm_iterative_match_sync(cluster2, tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(6_000, side=60.0))
    a, b = tmp_path / "a.laz", tmp_path / "b.laz"
    kw = dict(method="fcm", rule="iterative", cluster_size=150, cell_size=1_500, chunk_size=2_000, seed=3)
    sa = simplify(src, a, scheduler="sync", **kw)
    sb = simplify(src, b, scheduler=cluster2.scheduler.address, **kw)
    assert digest(a) == digest(b)
    assert sa.kept == sb.kept < 6_000
    assert sb.scheduler.startswith("distributed")


# ----------------------------------------------------------------- conservation


def test_conservation_per_cell_and_exactly_once(real_laz, tmp_path):
    store = tmp_path / "work.zarr"
    out = tmp_path / "out.laz"
    s = simplify(real_laz, out, store=store, scheduler="threads", cell_size=6_000, chunk_size=10_000, **FAST)
    st = PointStore.open(str(store))
    part = P.Partition.load(st)
    g = st.group
    n = st.count
    # every point in exactly one cell core
    labels = np.asarray(g["partition/cell"][:])
    assert np.array_equal(np.bincount(labels, minlength=part.n_cells), part.cell_counts)
    xyz = st.read("xyz")
    cores = [R.read_runs(g, part.runs(j)) for j in range(part.n_cells)]
    allpts = np.concatenate(cores)
    assert len(allpts) == n
    key = lambda a: a[np.lexsort(a.T[::-1])]  # noqa: E731
    assert np.array_equal(key(allpts), key(xyz))
    # per cell: in = kept + dropped; the cells' kept points are the output
    regions, _ = workstore.regions(part.cell_counts, workstore.region_block(6_000))
    kc = np.asarray(g["simplify/keep_cells"][:])
    keep = np.asarray(g["simplify/keep"][:])
    total_kept = 0
    for j in range(part.n_cells):
        nj = int(part.cell_counts[j])
        mask = kc[regions[j] : regions[j] + nj]
        kept_j = int(mask.sum())
        dropped_j = nj - kept_j
        assert kept_j + dropped_j == nj == int((labels == j).sum())
        assert kept_j == int(keep[labels == j].sum())
        # the cell's kept points are exactly its points kept in input order
        assert np.array_equal(cores[j][mask], xyz[(labels == j) & keep])
        total_kept += kept_j
    assert total_kept == s.kept == int(keep.sum())
    assert s.kept + s.removed == s.points_in == n
    # the output holds the kept points, in input order, with their attributes
    src = laspy.read(str(real_laz))
    res = laspy.read(str(out))
    assert len(res.points) == s.kept
    assert np.array_equal(res.X, src.X[keep]) and np.array_equal(res.intensity, src.intensity[keep])
    assert np.array_equal(res.gps_time, src.gps_time[keep])
    # the summary is stored in the store
    assert st.attrs["cloudsieve_simplify"]["summary"]["kept"] == s.kept


# ----------------------------------------------------------------- seams


def _border_density_ratio(xyz_in, keep, centers, labels, radius):
    s = np.full(len(xyz_in), np.inf)
    for i in range(len(centers)):
        other = labels != i
        d = H.halo_distance(xyz_in[other], centers[i], centers[labels[other]])
        s[other] = np.minimum(s[other], d)
    near = s <= radius
    return keep[near].mean() / keep[~near].mean(), near.sum()


@pytest.mark.parametrize("context", [False, True])
@pytest.mark.parametrize("ratio", [None, 0.5])
def test_no_seams_at_cell_borders(tmp_path, ratio, context):
    rng = np.random.default_rng(11)
    n = 10_000
    xyz = np.c_[rng.random((n, 2)) * 100.0, np.zeros(n)]
    src = write_laz(tmp_path / "plane.laz", xyz)
    store = tmp_path / "w.zarr"
    cluster_size = 100
    s = simplify(
        src, tmp_path / "o.laz", store=store, method="km", rule="iterative", ratio=ratio, halo_context=context,
        cluster_size=cluster_size, cell_size=1_250, chunk_size=4_000, scheduler="threads",
    )
    assert s.cells >= 8
    st = PointStore.open(str(store))
    g = st.group
    part = P.Partition.load(st)
    labels = np.asarray(g["partition/cell"][:])
    keep = np.asarray(g["simplify/keep"][:])
    pts = st.read("xyz")
    rho = n / 100.0**2
    radius = math.sqrt(cluster_size / (math.pi * rho))  # one cluster radius
    ratio_near, n_near = _border_density_ratio(pts, keep, part.centers, labels, radius)
    assert n_near > 1_000
    assert 0 < keep.mean() < 1
    assert abs(ratio_near - 1.0) <= 0.10, (ratio_near, keep.mean())


# ----------------------------------------------------------------- targets


@pytest.mark.parametrize("rule, ratio, count", [("target", 0.3, None), ("target", None, 9_000), ("iterative", 0.6, None)])
def test_ratio_and_count_across_cells_within_one_percent(tmp_path, rule, ratio, count):
    src = write_laz(tmp_path / "p.laz", plane(20_000, side=120.0, seed=4))
    s = simplify(
        src, tmp_path / "o.laz", method="km", rule=rule, ratio=ratio, count=count,
        cluster_size=200, cell_size=4_000, chunk_size=5_000, scheduler="threads",
    )
    want = count if count is not None else ratio * 20_000
    assert abs(s.kept - want) <= 0.01 * want
    assert s.threshold is not None and math.isfinite(s.threshold)
    assert len(laspy.read(str(tmp_path / "o.laz")).points) == s.kept


# ----------------------------------------------------------------- failures


def test_a_worker_killed_mid_run_changes_nothing(real_laz, tmp_path, cluster2, monkeypatch):
    src = write_laz(tmp_path / "p.laz", plane(24_000, side=150.0, seed=9))
    kw = dict(method="km", rule="iterative", cluster_size=200, cell_size=1_500, chunk_size=4_000, seed=2)
    ref = tmp_path / "ref.laz"
    simplify(src, ref, scheduler="threads", **kw)
    store = tmp_path / "w.zarr"
    out = tmp_path / "out.laz"
    result: dict = {}
    # the first cell task to start stops in its worker (the test hook of engine/pause.py; the rerun of that task
    # on a worker runs on): that worker is killed while it holds a task, whatever the machine's speed
    marker = tmp_path / "paused"
    pause = f"task:cells#once={marker}"
    monkeypatch.setenv(PAUSE_ENV, pause)  # the driver (this process) wraps the tasks
    cluster2.run(lambda: os.environ.__setitem__(PAUSE_ENV, pause))  # the workers stop (a lambda: by value)

    def go():
        try:
            result["summary"] = simplify(src, out, store=store, client=cluster2, **kw)
        except BaseException as exc:  # pragma: no cover - reported below
            result["error"] = exc

    pids = set(cluster2.run(os.getpid).values())
    t = threading.Thread(target=go, daemon=True)
    t.start()
    try:
        deadline = time.monotonic() + 600  # a guard against a hang only
        while t.is_alive() and time.monotonic() < deadline and not (marker.exists() and marker.read_text().strip()):
            time.sleep(0.05)
        assert marker.exists(), "the run did not reach its pause"
        worker = int(marker.read_text())
        assert worker in pids
        os.kill(worker, signal.SIGKILL)
        t.join(600)
    finally:
        cluster2.run(lambda: os.environ.pop(PAUSE_ENV, None))  # the worker replacing the killed one never had it
    assert "error" not in result, result.get("error")
    assert digest(out) == digest(ref)
    cluster2.wait_for_workers(2, timeout=60)


def test_driver_killed_then_resume_recomputes_only_missing_cells(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(30_000, side=160.0, seed=5))
    args = [
        "simplify", str(src), str(tmp_path / "out.laz"), "--method", "km", "--rule", "iterative",
        "--cluster-size", "200", "--cell-size", "1500", "--chunk-size", "5000", "--seed", "1",
        "--store", str(tmp_path / "w.zarr"), "--scheduler", "threads", "--workers", "1",
    ]
    ref = tmp_path / "ref.laz"
    simplify(src, ref, method="km", rule="iterative", cluster_size=200, cell_size=1_500, chunk_size=5_000, seed=1, scheduler="sync")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # the run stops in its 4th cell task (one thread: 3 cells done; the test hook of engine/pause.py)
    marker = tmp_path / "paused"
    proc = kill_at(args, "task:cells#4", marker, env)
    done_path = tmp_path / "w.zarr"
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()
    assert not (tmp_path / "out.laz").exists()
    done = np.asarray(zarr.open_group(str(done_path), mode="r")["simplify/done"][:]).astype(bool)
    n_done, n_cells = int(done.sum()), len(done)
    assert n_done == 3 < n_cells
    out = tmp_path / "resumed.json"
    args[2] = str(tmp_path / "out.laz")
    rc = subprocess.run([sys.executable, "-m", "cloudsieve", *args, "--resume", "--json"], capture_output=True, env=env)
    assert rc.returncode == 0, rc.stderr.decode()
    summary = json.loads(rc.stdout.decode())
    out.write_text(json.dumps(summary))
    assert summary["cells_reused"] == n_done
    assert summary["cells_computed"] == n_cells - n_done
    assert digest(tmp_path / "out.laz") == digest(ref)


def test_rerun_with_the_same_store_reuses_everything(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(8_000, side=80.0))
    kw = dict(cell_size=2_000, chunk_size=3_000, scheduler="sync", store=tmp_path / "w.zarr", **FAST)
    a = simplify(src, tmp_path / "a.laz", **kw)
    b = simplify(src, tmp_path / "b.laz", **kw)
    assert a.cells_computed == a.cells and a.cells_reused == 0
    assert b.cells_computed == 0 and b.cells_reused == b.cells
    assert digest(tmp_path / "a.laz") == digest(tmp_path / "b.laz")


def test_a_store_with_the_older_dense_partition_layout_is_partitioned_again(tmp_path):
    """A work store left by a version with the dense (chunks x cells) counts table: rebuilt, same output."""
    src = write_laz(tmp_path / "p.laz", plane(8_000, side=80.0))
    kw = dict(cell_size=2_000, chunk_size=3_000, scheduler="sync", store=tmp_path / "w.zarr", **FAST)
    a = simplify(src, tmp_path / "a.laz", **kw)
    # turn the store into the version-1 layout
    g = zarr.open_group(str(tmp_path / "w.zarr"), mode="r+")
    labels = np.asarray(g["partition/cell"][:])
    counts = np.zeros((3, a.cells), dtype=np.int64)
    np.add.at(counts, (np.arange(len(labels)) // 3_000, labels), 1)
    for name in ("chunk_ptr", "chunk_runs", "cell_ptr", "cell_runs", "cell_count"):
        del g[f"partition/{name}"]
    g.create_array("partition/counts", data=counts, chunks=(1, a.cells))
    meta = dict(g.attrs[P.PARTITION_ATTR])
    meta["version"] = 1
    del meta["n_chunks"], meta["n_runs"]
    g.attrs.update({P.PARTITION_ATTR: meta})
    with pytest.raises(P.PartitionLayoutError, match="layout version 1"):
        P.Partition.load(PointStore.open(str(tmp_path / "w.zarr")))
    b = simplify(src, tmp_path / "b.laz", resume=True, **kw)
    assert b.cells_computed == b.cells == a.cells and b.cells_reused == 0
    assert digest(tmp_path / "a.laz") == digest(tmp_path / "b.laz")
    st = PointStore.open(str(tmp_path / "w.zarr"))
    assert st.attrs[P.PARTITION_ATTR]["version"] == P.PARTITION_VERSION
    assert "partition/counts" not in st.group


def test_resume_with_other_parameters_is_refused(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(4_000, side=60.0))
    kw = dict(cell_size=2_000, chunk_size=3_000, scheduler="sync", store=tmp_path / "w.zarr", method="km", rule="threshold", cluster_size=200)
    simplify(src, tmp_path / "a.laz", seed=1, **kw)
    with pytest.raises(ResumeMismatchError, match=r"seed: stored 1, asked 2"):
        simplify(src, tmp_path / "b.laz", seed=2, resume=True, **kw)
    # overwrite discards the old run
    s = simplify(src, tmp_path / "b.laz", seed=2, overwrite=True, **kw)
    assert s.cells_reused == 0


# ----------------------------------------------------------------- stores


def test_a_file_url_store_works_like_a_path(tmp_path, reference, real_laz):
    ref, _ = reference
    out = tmp_path / "out.laz"
    url = "file://" + str(tmp_path / "w.zarr")
    s = simplify(real_laz, out, store=url, scheduler="threads", cell_size=6_000, chunk_size=10_000, **FAST)
    assert digest(out) == digest(ref)
    assert s.store == url
    assert (tmp_path / "w.zarr" / "partition").is_dir()


def test_a_store_as_source(tmp_path, reference, real_laz):
    ref, _ = reference
    st = ingest(real_laz, tmp_path / "in.zarr", chunk_size=10_000)
    out = tmp_path / "out.laz"
    simplify(st.path, out, scheduler="sync", cell_size=6_000, **FAST)
    assert digest(out) == digest(ref)
    assert "simplify" in zarr.open_group(str(tmp_path / "in.zarr"), mode="r")


def test_default_work_store_is_removed_after_success(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(3_000, side=50.0))
    out = tmp_path / "o.laz"
    s = simplify(src, out, scheduler="sync", cell_size=1_000, chunk_size=1_000, **FAST)
    assert out.exists() and not Path(str(out) + ".cloudsieve.zarr").exists()
    assert s.store == ""


# ----------------------------------------------------------------- CLI, errors


def test_cli_prints_the_summary(tmp_path, capsys):
    src = write_laz(tmp_path / "p.laz", plane(3_000, side=50.0))
    rc = main([
        "simplify", str(src), str(tmp_path / "o.laz"), "--method", "km", "--rule", "threshold",
        "--cluster-size", "200", "--cell-size", "1000", "--chunk-size", "1000", "--scheduler", "sync",
    ])
    assert rc == 0
    out = capsys.readouterr().out
    assert "points in" in out and "kept" in out and "cells" in out and "peak memory" in out
    rc = main(["simplify", str(src), str(tmp_path / "o.laz"), "--rule", "threshold", "--scheduler", "sync"])
    assert rc == 2
    assert "exists" in capsys.readouterr().err


def test_bad_parameters_are_refused(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(500, side=10.0))
    with pytest.raises(InvalidParameterError, match="rule 'target' needs a ratio or a count"):
        simplify(src, tmp_path / "o.laz", rule="target")
    with pytest.raises(InvalidParameterError, match="not ratio=0.5"):
        simplify(src, tmp_path / "o.laz", rule="threshold", ratio=0.5)
    with pytest.raises(InvalidParameterError, match="unknown scheduler 'fast'"):
        simplify(src, tmp_path / "o.laz", scheduler="fast", method="km")
    with pytest.raises(InvalidParameterError, match=r"cell_size \(100\) must be >= cluster_size \(400\)"):
        simplify(src, tmp_path / "o.laz", cell_size=100, rule="iterative")
