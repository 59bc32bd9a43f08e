"""Object storage in and out, against a real S3 server (SeaweedFS, tests/s3server.py): every SRC form as a URL,
one LAZ and tiles + VPC out, a remote work store, the same bytes as the same run on local disk."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys

import pytest

import cloudsieve
from cloudsieve.errors import DestinationExistsError, SameSourceDestinationError

from conftest import shared_file


def _sha(path) -> str:
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def _remote_sha(fs, url: str) -> str:
    return hashlib.sha256(fs.cat_file(url.split("://", 1)[1])).hexdigest()


@pytest.fixture
def tiles(bucket, s3, tmp_path):
    """Two LAS tiles of autzen_trim (split by x), locally in tmp/tiles and under bucket/tiles/, a .lst of
    relative lines and a VPC of relative hrefs beside them on both sides."""
    import laspy
    import numpy as np

    from cloudsieve.io.vpc import describe_tile, write_vpc

    las = laspy.read(shared_file("autzen_trim.laz"))
    cut = np.median(las.x)
    folder = tmp_path / "tiles"
    folder.mkdir()
    for name, keep in (("t0.laz", las.x < cut), ("t1.laz", las.x >= cut)):
        part = laspy.LasData(las.header)
        part.points = las.points[keep]
        part.write(folder / name)
    (folder / "list.lst").write_text("t0.laz\nt1.laz\n")
    write_vpc(str(folder / "index.vpc"), [describe_tile(str(folder / n)) for n in ("t0.laz", "t1.laz")])
    fs = s3.filesystem()
    for name in ("t0.laz", "t1.laz", "list.lst", "index.vpc"):
        fs.put_file(str(folder / name), f"{bucket[5:]}/tiles/{name}")
    return folder


SOURCES = {"one file": "t0.laz", "glob": "*.laz", "prefix": "", "list": "list.lst", "vpc": "index.vpc"}


@pytest.mark.parametrize("form", list(SOURCES))
def test_every_source_form_as_a_url_gives_the_local_bytes(tiles, bucket, s3, tmp_path, form):
    rel = SOURCES[form]
    local_src = str(tiles) + "/" + rel if rel else str(tiles)
    remote_src = f"{bucket}/tiles/{rel}"
    a, b = tmp_path / "local.laz", tmp_path / "remote.laz"
    cloudsieve.simplify(local_src, a, ratio=0.5)
    cloudsieve.simplify(remote_src, b, ratio=0.5, storage_options=s3.storage_options())
    assert _sha(a) == _sha(b)


def test_out_of_core_s3_to_s3_one_laz_and_a_remote_store(tiles, bucket, s3, tmp_path):
    """Ingest tasks read byte ranges of the remote tiles, the work store is on S3, the parts are uploaded by
    the tasks and assembled by one: the same file as local -> local; nothing left beside it."""
    opts = s3.storage_options()
    local = tmp_path / "local.laz"
    cloudsieve.simplify(str(tiles / "*.laz"), local, ratio=0.5, workers=2, chunk_size=20_000)
    dst = f"{bucket}/out/small.laz"
    fs = s3.filesystem()
    for stale in (".small.laz.parts-0123456789ab/part-000000.laz", ".small.laz.scratch-0123456789ab/up-0.bin"):
        fs.pipe_file(f"{bucket[5:]}/out/{stale}", b"left by a run that was killed")
    summary = cloudsieve.simplify(f"{bucket}/tiles/*.laz", dst, ratio=0.5, workers=2, chunk_size=20_000,
                                  store=f"{bucket}/work.zarr", storage_options=opts)
    assert summary.kept == 55_000
    assert _remote_sha(fs, dst) == _sha(local)
    fs.invalidate_cache()
    # no parts left, neither this run's nor those of a run killed before
    assert sorted(fs.find(f"{bucket[5:]}/out")) == [f"{bucket[5:]}/out/small.laz"]
    from cloudsieve import storage
    from cloudsieve.store import PointStore

    with storage.using(opts):  # a named work store is kept after success, on S3 as on disk
        assert PointStore.open(f"{bucket}/work.zarr").count == 110_000


def test_tiles_and_vpc_to_a_prefix(tiles, bucket, s3, tmp_path):
    """Tiles under the final prefix, index.vpc last with relative hrefs; the same tiles as a local run; a
    rerun with overwrite removes the tiles the new set does not have; foreign objects are never replaced."""
    opts = s3.storage_options()
    fs = s3.filesystem()
    cloudsieve.simplify(str(tiles / "t0.laz"), tmp_path / "tl", ratio=0.5, tile_size=300.0, workers=2)
    dst = f"{bucket}/tl"
    cloudsieve.simplify(f"{bucket}/tiles/t0.laz", dst, ratio=0.5, tile_size=300.0, workers=2, storage_options=opts)
    local = sorted(os.listdir(tmp_path / "tl"))
    fs.invalidate_cache()
    assert sorted(p.rsplit("/", 1)[1] for p in fs.find(dst[5:])) == local
    for name in local:
        if name.endswith(".laz"):
            assert _remote_sha(fs, f"{dst}/{name}") == _sha(tmp_path / "tl" / name)
    doc = json.loads(fs.cat_file(f"{dst[5:]}/index.vpc"))
    assert [f["assets"]["data"]["href"] for f in doc["features"]] == [f"./{n}" for n in local if n != "index.vpc"]
    with pytest.raises(DestinationExistsError):
        cloudsieve.simplify(f"{bucket}/tiles/t0.laz", dst, ratio=0.5, tile_size=300.0, storage_options=opts)
    cloudsieve.simplify(f"{bucket}/tiles/t0.laz", dst, ratio=0.5, tile_size=600.0, workers=2,
                        storage_options=opts, overwrite=True)
    fs.invalidate_cache()
    names = sorted(p.rsplit("/", 1)[1] for p in fs.find(dst[5:]))
    doc = json.loads(fs.cat_file(f"{dst[5:]}/index.vpc"))
    assert names == sorted(["index.vpc"] + [f["assets"]["data"]["href"][2:] for f in doc["features"]])
    fs.pipe_file(f"{dst[5:]}/notes.txt", b"mine")
    with pytest.raises(DestinationExistsError, match=r"holds 1 entry other than its tiles and index.vpc "
                                                     r"\(notes.txt\)"):
        cloudsieve.simplify(f"{bucket}/tiles/t0.laz", dst, ratio=0.5, tile_size=600.0, storage_options=opts,
                            overwrite=True)


def test_a_url_destination_is_checked_as_a_path(tiles, bucket, s3):
    opts = s3.storage_options()
    src = f"{bucket}/tiles/t0.laz"
    with pytest.raises(SameSourceDestinationError):
        cloudsieve.simplify(src, src, ratio=0.5, overwrite=True, storage_options=opts)
    with pytest.raises(SameSourceDestinationError):
        cloudsieve.simplify(src, f"{bucket}/tiles", ratio=0.5, tile_size=500.0, overwrite=True, storage_options=opts)
    with pytest.raises(DestinationExistsError, match=r"tiles/t1.laz exists; pass overwrite=True to replace it"):
        cloudsieve.simplify(src, f"{bucket}/tiles/t1.laz", ratio=0.5, storage_options=opts)


def _cli(args, env=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "cloudsieve", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=timeout)


def test_the_environment_chain_with_no_option_and_info_on_urls(tiles, bucket, s3, tmp_path):
    """AWS_* variables (AWS_ENDPOINT_URL among them) are enough; info describes an object and a prefix."""
    env = s3.env()
    proc = _cli(["info", f"{bucket}/tiles/t0.laz"], env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0] == f"{bucket}/tiles/t0.laz: laz"
    proc = _cli(["info", f"{bucket}/tiles/", "--json"], env)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["total"]["count"] == 110_000
    out = tmp_path / "o.laz"
    proc = _cli(["simplify", f"{bucket}/tiles/*.laz", str(out), "--ratio", "0.5", "--json"], env)
    assert proc.returncode == 0, proc.stderr
    secret = s3.keys().secret
    assert secret not in proc.stdout + proc.stderr
    assert json.loads(proc.stdout)["kept"] == 55_000


def test_storage_options_on_the_command_line_never_show_their_secret(tiles, bucket, s3, tmp_path):
    opts = s3.storage_options()
    bad = {**opts, "secret": "wrong-secret-value-1234"}
    proc = _cli(["simplify", f"{bucket}/tiles/t0.laz", str(tmp_path / "o.laz"), "--ratio", "0.5",
                 "--storage-options", json.dumps(bad)])
    assert proc.returncode == 2
    assert "wrong-secret-value-1234" not in proc.stderr + proc.stdout
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    proc = _cli(["simplify", f"{bucket}/tiles/t0.laz", str(tmp_path / "o.laz"), "--ratio", "0.5",
                 "--storage-options", json.dumps(opts)])
    assert proc.returncode == 0, proc.stderr
    assert opts["secret"] not in proc.stderr + proc.stdout


def test_bad_remote_inputs_and_destinations_are_one_line_and_status_2(tiles, bucket, s3, tmp_path):
    """Each: exit 2, the one line below, no traceback, nothing under the final name."""
    env, ro = s3.env(), s3.env(readonly=True)
    b = bucket
    cases = [
        (["s3://no-such-bucket-cs/a.laz", "o1.laz"], env, "s3://no-such-bucket-cs/a.laz: no such bucket"),
        ([f"{b}/tiles/missing.laz", "o2.laz"], env, f"{b}/tiles/missing.laz: no such file"),
        (["s3://Bad_Bucket!/a.laz", "o3.laz"], env, "s3://Bad_Bucket!/a.laz: invalid bucket name (S3 bucket names "
         "are 3 to 63 lower-case letters, digits, dots and hyphens)"),
        ([f"{b}/tiles/*.las", "o4.laz"], env, f"{b}/tiles/*.las: the pattern matches no file"),
        ([f"{b}/tiles/t0.laz", f"{b}/out/o5.laz"], ro,
         f"{b}/out/o5.laz: access denied: cannot write it with these credentials (Access Denied.)"),
        ([f"{b}/tiles/t0.laz", "s3://no-such-bucket-cs/o6.laz"], env,
         "cannot write s3://no-such-bucket-cs/o6.laz: bucket no-such-bucket-cs does not exist"),
    ]
    for args, environment, line in cases:
        proc = subprocess.run([sys.executable, "-m", "cloudsieve", "simplify", *args, "--ratio", "0.5"],
                              cwd=tmp_path, capture_output=True, text=True, env={**os.environ, **environment},
                              timeout=120)
        assert (proc.returncode, proc.stderr.strip().splitlines()) == (2, [f"cloudsieve simplify: error: {line}"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]
    fs = s3.filesystem()
    fs.invalidate_cache()
    assert not fs.find(f"{b[5:]}/out")


def test_an_unreachable_endpoint_fails_within_a_minute_naming_it(tiles, tmp_path):
    env = {"AWS_ENDPOINT_URL": "http://127.0.0.1:9", "AWS_ENDPOINT_URL_S3": "http://127.0.0.1:9",
           "AWS_ACCESS_KEY_ID": "k", "AWS_SECRET_ACCESS_KEY": "s", "AWS_EC2_METADATA_DISABLED": "true"}
    proc = _cli(["simplify", "s3://somewhere/a.laz", str(tmp_path / "o.laz"), "--ratio", "0.5"], env, timeout=60)
    assert proc.returncode == 2
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith("cloudsieve simplify: error: s3://somewhere/a.laz: cannot reach the object store at "
                           "http://127.0.0.1:9 (")


def test_the_server_stopped_mid_run_then_resume_gives_the_same_bytes(tiles, bucket, s3, tmp_path):
    """The run stops at the cells (its work store on S3), the server stops, the run goes on and fails with one
    line; the server comes back and --resume finishes: the same file as an uninterrupted run."""
    import time

    from cloudsieve.engine.pause import PAUSE_ENV

    env = s3.env()
    base = [f"{bucket}/tiles/*.laz", "--ratio", "0.5", "--workers", "2", "--chunk-size", "20000",
            "--store", f"{bucket}/work.zarr"]
    whole = _cli(["simplify", base[0], str(tmp_path / "whole.laz"), *base[1:7]], env, timeout=300)
    assert whole.returncode == 0, whole.stderr
    marker = tmp_path / "paused"
    run = subprocess.Popen([sys.executable, "-m", "cloudsieve", "simplify", base[0], f"{bucket}/o.laz", *base[1:]],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env={**os.environ, **env, PAUSE_ENV: f"driver:cells: apply={marker}"})
    try:
        deadline = time.monotonic() + 300
        while not marker.exists() and run.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert marker.exists(), run.communicate()[1]
        s3.stop()
        marker.unlink()  # the run goes on, without its server
        _, err = run.communicate(timeout=300)
    finally:
        if run.poll() is None:
            run.kill()
        if not s3.running:
            s3.start()
    assert run.returncode == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"cloudsieve simplify: error: {bucket}/work.zarr: cannot reach the object store at "
                           f"{s3.endpoint_url} (")
    assert "Traceback" not in err
    fs = s3.filesystem()
    assert not fs.exists(f"{bucket[5:]}/o.laz")
    again = _cli(["simplify", base[0], f"{bucket}/o.laz", *base[1:], "--resume"], env, timeout=300)
    assert again.returncode == 0, again.stderr
    assert _remote_sha(fs, f"{bucket}/o.laz") == _sha(tmp_path / "whole.laz")


def test_evaluate_compare_ingest_export_and_pipelines_take_urls(tiles, bucket, s3, tmp_path):
    """Reports go under a URL prefix (written locally, then uploaded); a pipeline reads and writes URLs; nothing
    is made on the local disk for a URL."""
    env = s3.env()
    src = f"{bucket}/tiles/t0.laz"
    run = lambda *a: _cli(list(a), env, timeout=300)  # noqa: E731
    for args in (["simplify", src, f"{bucket}/o.laz", "--ratio", "0.5"],
                 ["evaluate", src, f"{bucket}/o.laz", "--no-surface", "--report", f"{bucket}/rep"],
                 ["compare", src, "--ratio", "0.5", "--no-surface", "--methods", "random", "--report", f"{bucket}/cmp"],
                 ["ingest", src, f"{bucket}/st.zarr"],
                 ["export", f"{bucket}/st.zarr", f"{bucket}/e.laz"]):
        proc = run(*args)
        assert proc.returncode == 0, proc.stderr
    fs = s3.filesystem()
    fs.invalidate_cache()
    report = json.loads(fs.cat_file(f"{bucket[5:]}/rep/report.json"))
    assert report["files"]["html"] == f"{bucket}/rep/report.html"
    assert fs.exists(f"{bucket[5:]}/cmp/report.html")
    pipeline = tmp_path / "p.json"
    pipeline.write_text(json.dumps({"pipeline": [{"type": "readers.las", "filename": f"{bucket}/tiles/t*.laz"},
                                                 {"type": "filters.entropy", "ratio": 0.5},
                                                 {"type": "writers.las", "filename": f"{bucket}/p/{{stem}}.laz"}]}))
    proc = _cli(["run", str(pipeline)], env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    fs.invalidate_cache()
    assert sorted(fs.ls(f"{bucket[5:]}/p")) == [f"{bucket[5:]}/p/t0.laz", f"{bucket[5:]}/p/t1.laz"]
    assert not os.path.exists("s3:")


@pytest.mark.parametrize("ext", ["ply", "xyz", "copc.laz"])
def test_other_formats_to_a_url_give_the_local_bytes(tiles, bucket, s3, tmp_path, ext):
    opts = s3.storage_options()
    local = tmp_path / f"o.{ext}"
    cloudsieve.simplify(str(tiles / "t0.laz"), local, ratio=0.5)
    cloudsieve.simplify(str(tiles / "t0.laz"), f"{bucket}/o.{ext}", ratio=0.5, storage_options=opts)
    assert _remote_sha(s3.filesystem(), f"{bucket}/o.{ext}") == _sha(local)


def test_stale_scratch_removal_keeps_sources_and_names_not_cloudsieve_s(bucket, s3):
    """Only cloudsieve's own scratch names beside DST (``.<name>.parts-<12 hex>`` ...) are removed: an object
    of another name, and a source under a scratch name, keep their bytes."""
    from cloudsieve import staging, storage

    fs = s3.filesystem()
    root = f"{bucket[5:]}/out"
    left = f"{root}/.small.laz.parts-0123456789ab/part-000000.laz"
    mine = f"{root}/.small.laz.parts-mine/notes.txt"
    source = f"{root}/.small.laz.scratch-abcdefabcdef/input.laz"
    for key in (left, mine, source):
        fs.pipe_file(key, b"bytes")
    with storage.using(s3.storage_options()):
        staging.remove_stale_scratch(f"{bucket}/out/small.laz", [f"s3://{source}"])
    fs.invalidate_cache()
    assert sorted(fs.find(root)) == sorted([mine, source])
    assert fs.cat_file(mine) == fs.cat_file(source) == b"bytes"
