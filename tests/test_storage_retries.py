"""The object store's retries, counted in the summary, against a real S3 server (SeaweedFS, tests/s3server.py):
none on a healthy run; the server stopped (SIGSTOP) for longer than the read timeout while the workers read the
work store, then resumed (SIGCONT): the requests are sent again, counted, and the run gives the same bytes."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from cloudsieve.engine.pause import PAUSE_ENV

from conftest import shared_file


@pytest.fixture
def cloud(bucket, s3):
    """autzen_trim.laz (110,000 points) as the object bucket/in/a.laz."""
    s3.filesystem().put_file(str(shared_file("autzen_trim.laz")), f"{bucket[5:]}/in/a.laz")
    return f"{bucket}/in/a.laz"


def _cli(args, env=None, timeout=300, **kwargs):
    return subprocess.run([sys.executable, "-m", "cloudsieve", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=timeout, **kwargs)


def _remote_sha(s3, url: str) -> str:
    fs = s3.filesystem()
    return hashlib.sha256(fs.cat_file(url.split("://", 1)[1])).hexdigest()


def test_a_healthy_run_counts_no_retry_and_a_local_run_has_no_storage_entry(cloud, bucket, s3, tmp_path):
    opts = json.dumps(s3.storage_options())
    proc = _cli(["simplify", cloud, f"{bucket}/o.laz", "--ratio", "0.5", "--json", "--storage-options", opts])
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["storage"] == {"retries": 0}
    proc = _cli(["simplify", cloud, f"{bucket}/o2.laz", "--ratio", "0.5", "--storage-options", opts])
    assert proc.returncode == 0, proc.stderr
    assert [line for line in proc.stdout.splitlines() if line.startswith("storage")] == [
        "storage                    0  retries (requests sent again after a timeout, throttling or a 5xx)"]
    local = tmp_path / "a.laz"
    local.write_bytes(shared_file("autzen_trim.laz").read_bytes())
    proc = _cli(["simplify", str(local), str(tmp_path / "o.laz"), "--ratio", "0.5", "--json"])
    assert proc.returncode == 0, proc.stderr
    assert "storage" not in json.loads(proc.stdout)


def test_the_server_stopped_longer_than_the_read_timeout_is_retried_counted_and_gives_the_same_bytes(
        cloud, bucket, s3, tmp_path):
    """The run stops before its cells (work store on S3, two worker processes); the server is stopped, the run
    goes on and its requests wait; 4 s later (the read timeout is 1 s) the server goes on: the run succeeds
    with the bytes of an uninterrupted run, and its summary counts the retries."""
    opts = {**s3.storage_options(), "config_kwargs": {"read_timeout": 1}}
    args = [cloud, "--ratio", "0.5", "--workers", "2", "--chunk-size", "20000", "--json",
            "--storage-options", json.dumps(opts)]
    whole = _cli(["simplify", args[0], f"{bucket}/whole.laz", *args[1:], "--store", f"{bucket}/w0.zarr"])
    assert whole.returncode == 0, whole.stderr
    marker = tmp_path / "paused"
    run = subprocess.Popen([sys.executable, "-m", "cloudsieve", "simplify", args[0], f"{bucket}/o.laz", *args[1:],
                            "--store", f"{bucket}/w1.zarr"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, env={**os.environ, PAUSE_ENV: f"driver:cells: apply={marker}"})
    stopped = False
    try:
        deadline = time.monotonic() + 300
        while not marker.exists() and run.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert marker.exists(), run.communicate()[1]
        os.kill(s3.pid, signal.SIGSTOP)
        stopped = True
        marker.unlink()  # the run goes on; its requests get no answer
        time.sleep(4)
        os.kill(s3.pid, signal.SIGCONT)
        stopped = False
        out, err = run.communicate(timeout=300)
    finally:
        if stopped:
            os.kill(s3.pid, signal.SIGCONT)
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, err
    assert json.loads(out)["storage"]["retries"] >= 1
    assert _remote_sha(s3, f"{bucket}/o.laz") == _remote_sha(s3, f"{bucket}/whole.laz")


def test_the_retry_settings_stay_as_set_and_a_url_s_filesystem_is_made_once(bucket, s3):
    """botocore rewrites the "retries" it is given ({"max_attempts": n} becomes {"total_max_attempts": n + 1}):
    each filesystem gets its own copy, so the next one is made with the same settings, and is the same
    (cached) filesystem, not a second client (about 0.1 s of CPU in every process)."""
    from cloudsieve import storage

    with storage.using(s3.storage_options()):
        first, path = storage.filesystem(f"{bucket}/a")
        assert not first.exists(path)  # a request: the client is made
        again, _ = storage.filesystem(f"{bucket}/b")
        assert again is first
        assert storage.fs_options(bucket)["config_kwargs"] == {
            "connect_timeout": 10, "read_timeout": 60, "retries": {"total_max_attempts": 4, "mode": "standard"}}
