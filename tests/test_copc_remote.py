"""COPC output to an object store (store/copc.py, store/copc_scratch.py, store/copc_file.py) on a real S3 server.

The file written to ``s3://bucket/x.copc.laz`` is the same, byte for byte, as the one written to a local path
from the same store; a failure leaves no object under the destination's name nor under the scratch prefix
beside it, and no multipart upload open; an existing destination is refused without overwrite and replaced
with it. The server is SeaweedFS (tests/s3server.py, the ``s3`` and ``bucket`` fixtures of conftest.py).
"""

from __future__ import annotations

import hashlib
import tempfile

import pytest
from conftest import shared_file

import cloudsieve
from cloudsieve import storage
from cloudsieve.engine.runner import Runner
from cloudsieve.errors import DestinationExistsError, DestinationNotWritableError, InputNotReadableError
from cloudsieve.store import ingest
from cloudsieve.store.copc import export_copc

SMALL = {"task_points": 12_000, "leaf_points": 3_000}  # many subtree tasks and ancestor batches on 110 000 points


@pytest.fixture(scope="module")
def src() -> str:
    return str(shared_file("autzen_trim.laz"))


@pytest.fixture(scope="module")
def local_simplified(src, tmp_path_factory) -> bytes:
    """The COPC simplify writes to a local path (the reference bytes)."""
    dst = tmp_path_factory.mktemp("local") / "x.copc.laz"
    cloudsieve.simplify(src, str(dst), ratio=0.5, workers=2)
    return dst.read_bytes()


@pytest.fixture(scope="module")
def autzen_store(src, tmp_path_factory):
    """autzen_trim.laz (110 000 points) in a local store of 16 000-point chunks."""
    return ingest(src, tmp_path_factory.mktemp("s") / "s.zarr", chunk_size=16_000)


@pytest.fixture(scope="module")
def local_small(autzen_store, tmp_path_factory) -> bytes:
    """export_copc of the whole store with SMALL to a local path."""
    dst = tmp_path_factory.mktemp("small") / "x.copc.laz"
    export_copc(autzen_store, str(dst), **SMALL)
    return dst.read_bytes()


@pytest.fixture
def local_temp(tmp_path, monkeypatch):
    """The tasks' temporary folder (run in this process) as an empty folder of the test's own."""
    folder = tmp_path / "worker-tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def objects(s3, bucket: str) -> list[str]:
    """Every object of *bucket* (``s3://name``), as URLs; the prefixes SeaweedFS keeps once emptied are not objects."""
    fs = s3.filesystem()
    return sorted(f"s3://{k}" for k in fs.find(bucket.removeprefix("s3://")))


def open_uploads(s3, bucket: str) -> list:
    return s3.client().list_multipart_uploads(Bucket=bucket.removeprefix("s3://")).get("Uploads", [])


def tasks_with(options: dict, stages: tuple[str, ...] | None = None):
    """A runner running the tasks here, one after the other: those of *stages* (None: all) with the storage
    options *options* (a worker with another identity than the driver's)."""

    def run(func, args, stage):
        if stages is not None and stage not in stages:
            return [func(*a) for a in args]
        with storage.using(options):
            return [func(*a) for a in args]

    return run


def test_simplify_to_s3_same_bytes_as_local(s3, bucket, src, local_simplified):
    dst = f"{bucket}/out/x.copc.laz"
    cloudsieve.simplify(src, dst, ratio=0.5, workers=2, storage_options=s3.storage_options())
    got = s3.filesystem().cat(dst)
    assert sha(got) == sha(local_simplified) and got[:4] == b"LASF"
    assert objects(s3, bucket) == [dst]  # no scratch, no work store left


def test_simplify_s3_source_to_s3_same_bytes_as_local(s3, bucket, src, local_simplified):
    remote_src = f"{bucket}/in/autzen_trim.laz"
    s3.filesystem().put_file(src, remote_src)
    dst = f"{bucket}/out/x.copc.laz"
    cloudsieve.simplify(remote_src, dst, ratio=0.5, workers=2, storage_options=s3.storage_options())
    assert sha(s3.filesystem().cat(dst)) == sha(local_simplified)
    assert objects(s3, bucket) == [remote_src, dst]


def test_many_tasks_on_two_processes_same_bytes_as_local(s3, bucket, autzen_store, local_small):
    """Subtree scratch files uploaded by one process, read by ranges by others (ancestors, the file)."""
    dst = f"{bucket}/x.copc.laz"
    run = Runner("processes", workers=2)
    try:
        with storage.using(s3.storage_options()):
            out = export_copc(autzen_store, dst, run=run, **SMALL)
    finally:
        run.close()
    assert out["tasks"] > 4 and out["depth"] >= 3
    assert out["bytes"] == len(local_small)
    assert sha(s3.filesystem().cat(dst)) == sha(local_small)
    assert objects(s3, bucket) == [dst] and open_uploads(s3, bucket) == []


@pytest.mark.parametrize("stages, names", [
    (None, "scratch"),  # every task: the first subtree's scratch upload is refused
    (("export: copc file",), "dst"),  # the final task only: the scratch is written, the file is refused
], ids=["every-task", "final-task"])
def test_a_refused_write_leaves_no_object(s3, bucket, autzen_store, local_temp, stages, names):
    dst = f"{bucket}/x.copc.laz"
    run = tasks_with(s3.storage_options(readonly=True), stages)
    with storage.using(s3.storage_options()):
        with pytest.raises(DestinationNotWritableError) as info:
            export_copc(autzen_store, dst, run=run, **SMALL)
    message = str(info.value)
    assert "\n" not in message and "access denied" in message
    assert s3.admin.secret not in message and s3.readonly.secret not in message
    if names == "dst":
        assert message.startswith(f"{dst}: ")
    else:
        assert message.startswith(f"{bucket}/.x.copc.laz.scratch-") and "/up-0.bin: " in message
    assert objects(s3, bucket) == [] and open_uploads(s3, bucket) == []
    assert list(local_temp.iterdir()) == []  # the tasks' local scratch files removed


def test_a_failure_while_writing_keeps_the_old_object(s3, bucket, autzen_store, local_temp, monkeypatch):
    """A failure in the middle of the final file (a scratch read after the header went out) with overwrite:
    the object under dst stays the old one, nothing else is left."""
    dst = f"{bucket}/x.copc.laz"
    s3.filesystem().pipe_file(dst, b"old")
    read_range = storage.read_range
    calls = []

    def failing_read(path, start, length):
        calls.append(path)
        if len(calls) > 3:
            with storage.remote_errors(path):
                raise ConnectionResetError("connection reset by peer")
        return read_range(path, start, length)

    def run(func, args, stage):
        if stage == "export: copc file":
            monkeypatch.setattr(storage, "read_range", failing_read)
        try:
            return [func(*a) for a in args]
        finally:
            monkeypatch.setattr(storage, "read_range", read_range)

    with storage.using(s3.storage_options()):
        with pytest.raises(InputNotReadableError, match="connection reset by peer") as info:
            export_copc(autzen_store, dst, run=run, overwrite=True, **SMALL)
    assert len(calls) == 4 and "\n" not in str(info.value)
    assert str(info.value).startswith(f"{bucket}/.x.copc.laz.scratch-")  # the object that could not be read
    assert s3.filesystem().cat(dst) == b"old"
    assert objects(s3, bucket) == [dst] and open_uploads(s3, bucket) == []
    assert list(local_temp.iterdir()) == []


def test_existing_destination_refused_then_replaced(s3, bucket, src, autzen_store, local_small):
    dst = f"{bucket}/x.copc.laz"
    fs = s3.filesystem()
    fs.pipe_file(dst, b"old")
    with pytest.raises(DestinationExistsError, match=rf"^{dst} exists; pass overwrite=True to replace it$"):
        cloudsieve.simplify(src, dst, ratio=0.5, workers=2, storage_options=s3.storage_options())
    with storage.using(s3.storage_options()):
        with pytest.raises(DestinationExistsError, match=rf"^{dst} exists; pass overwrite=True"):
            export_copc(autzen_store, dst, **SMALL)
        assert fs.cat(dst) == b"old" and objects(s3, bucket) == [dst]
        export_copc(autzen_store, dst, overwrite=True, **SMALL)
    assert sha(fs.cat(dst)) == sha(local_small)
    assert objects(s3, bucket) == [dst]


def test_scratch_removal_failure_is_logged_not_raised(s3, bucket, caplog):
    """The scratch's removal runs in a finally: its own error must not replace the export's."""
    from cloudsieve.store.copc_scratch import make_scratch, remove_scratch

    scratch = make_scratch(f"{bucket}/x.copc.laz")
    s3.filesystem().pipe_file(f"{scratch}/up-0.bin", b"records")
    with storage.using(s3.storage_options(readonly=True)):
        remove_scratch(scratch)
    assert "could not remove the scratch objects under " + scratch in caplog.text
    with storage.using(s3.storage_options()):
        remove_scratch(scratch)
    assert objects(s3, bucket) == []
