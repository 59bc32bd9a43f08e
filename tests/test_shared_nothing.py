"""A shared-nothing cluster: a ``dask scheduler`` and two ``dask worker`` processes started in empty folders of
their own (their own TMPDIR, no AWS variables), the driver in a third; every path a URL on S3 (SeaweedFS). The
workers get what they need through the tasks (the storage options among them) and the object store alone:
the same bytes as the same run on local disk: one LAZ, tiles + VPC and one COPC."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time

import pytest

import cloudsieve

from conftest import shared_file


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _clean_env(folder) -> dict:
    """The environment of a process that shares nothing with the driver: no AWS_* variable, its own TMPDIR."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_") and not k.startswith("DASK_")}
    tmp = folder / "tmp"
    tmp.mkdir(exist_ok=True)
    env.update(TMPDIR=str(tmp), HOME=str(folder))
    return env


@pytest.fixture
def cluster(tmp_path):
    """``tcp://`` address of a scheduler and two single-threaded workers, each in an empty folder of its own."""
    dask = shutil.which("dask", path=os.path.dirname(sys.executable))
    if dask is None:
        pytest.skip("the dask command is not installed beside this Python")
    procs = []
    sched_dir, work_dir = tmp_path / "scheduler", tmp_path / "workers"
    sched_dir.mkdir()
    work_dir.mkdir()
    info = sched_dir / "scheduler.json"
    try:
        procs.append(subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                       "--scheduler-file", str(info)], cwd=sched_dir, env=_clean_env(sched_dir),
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        for i in range(2):
            folder = work_dir / f"w{i}"
            folder.mkdir()
            procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--no-dashboard",
                                           "--local-directory", str(folder / "tmp"), "--host", "127.0.0.1"],
                                          cwd=folder, env=_clean_env(folder),
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_a_shared_nothing_cluster_gives_the_local_bytes(cluster, bucket, s3, tmp_path, monkeypatch):
    fs = s3.filesystem()
    fs.put_file(str(shared_file("autzen_trim.laz")), f"{bucket[5:]}/in/a.laz")
    local = tmp_path / "local"
    local.mkdir()
    cloudsieve.simplify(shared_file("autzen_trim.laz"), local / "one.laz", ratio=0.5, workers=2, chunk_size=20_000)
    cloudsieve.simplify(shared_file("autzen_trim.laz"), local / "tl", ratio=0.5, workers=2, chunk_size=20_000,
                        tile_size=300.0)
    cloudsieve.simplify(shared_file("autzen_trim.laz"), local / "o.copc.laz", ratio=0.5, workers=2,
                        chunk_size=20_000)
    driver = tmp_path / "driver"
    driver.mkdir()
    monkeypatch.chdir(driver)
    for k in [k for k in os.environ if k.startswith("AWS_")]:
        monkeypatch.delenv(k)
    opts = s3.storage_options()
    run = {"ratio": 0.5, "chunk_size": 20_000, "scheduler": cluster, "storage_options": opts}
    summary = cloudsieve.simplify(f"{bucket}/in/a.laz", f"{bucket}/out/one.laz", **run)
    assert summary.storage == {"retries": 0}  # the workers' counts asked for, none on a healthy server
    cloudsieve.simplify(f"{bucket}/in/a.laz", f"{bucket}/out/tl", tile_size=300.0, **run)
    cloudsieve.simplify(f"{bucket}/in/a.laz", f"{bucket}/out/o.copc.laz", **run)
    fs.invalidate_cache()
    assert _sha(fs.cat_file(f"{bucket[5:]}/out/one.laz")) == _sha((local / "one.laz").read_bytes())
    assert _sha(fs.cat_file(f"{bucket[5:]}/out/o.copc.laz")) == _sha((local / "o.copc.laz").read_bytes())
    names = sorted(os.listdir(local / "tl"))
    assert sorted(p.rsplit("/", 1)[1] for p in fs.find(f"{bucket[5:]}/out/tl")) == names
    for name in names:
        if name.endswith(".laz"):
            assert _sha(fs.cat_file(f"{bucket[5:]}/out/tl/{name}")) == _sha((local / "tl" / name).read_bytes())
    assert sorted(os.listdir(driver)) == []  # the driver wrote nothing on its own disk
