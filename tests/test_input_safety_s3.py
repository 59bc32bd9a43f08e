"""No way to delete, overwrite or write into an input on object storage (a real S3 server, SeaweedFS,
tests/s3server.py): tests/test_input_safety.py's table for URLs. Every form of SRC (one object, a prefix with and
without "/", a glob, a .lst, a .vpc) against every DST that could reach it (the object, the prefix as a file, as
tiles, as COPC, as the work store, the prefix above), with and without overwrite: each is refused before any
work with the message below, and every object in the bucket keeps its bytes (its ETag), none is added."""

from __future__ import annotations

import shutil
import uuid

import pytest

import cloudsieve
from cloudsieve.errors import DestinationExistsError, SameSourceDestinationError

from conftest import shared_file

NAMES = ("a.laz", "b.laz", "list.lst", "index.vpc")


@pytest.fixture(scope="module")
def inputs(s3, tmp_path_factory):
    """One bucket for the module: data/in/{a,b}.laz (simple.laz, 1,065 points each), data/in/list.lst
    (relative lines) and data/in/index.vpc (relative hrefs); returns (bucket URL, the admin's options)."""
    from cloudsieve.io.vpc import describe_tile, write_vpc

    if not s3.running:
        s3.start()
    folder = tmp_path_factory.mktemp("in")
    for name in ("a.laz", "b.laz"):
        shutil.copy(shared_file("simple.laz"), folder / name)
    (folder / "list.lst").write_text("a.laz\nb.laz\n")
    write_vpc(str(folder / "index.vpc"), [describe_tile(str(folder / n)) for n in ("a.laz", "b.laz")])
    name = f"safety-{uuid.uuid4().hex[:10]}"
    bucket = s3.make_bucket(name)
    fs = s3.filesystem()
    for n in NAMES:
        fs.put_file(str(folder / n), f"{name}/data/in/{n}")
    fs.pipe_file(f"{name}/other/notes.txt", b"mine")
    yield bucket, s3.storage_options(), folder
    s3.remove_bucket(name)


@pytest.fixture
def unchanged(inputs, s3):
    """Asserts after the test that every object of the bucket is as it was (else puts the inputs back, so
    the next tests start from them)."""
    bucket, _, folder = inputs

    def listing() -> dict:
        return {k: v.get("ETag") for k, v in s3.filesystem().find(bucket[5:], detail=True).items()}

    before = listing()
    yield
    after = listing()
    if after != before:
        fs = s3.filesystem()
        for key in set(after) - set(before):
            fs.rm(key)
        for n in NAMES:
            fs.put_file(str(folder / n), f"{bucket[5:]}/data/in/{n}")
    assert after == before


SOURCES = {
    "object": "data/in/a.laz",
    "prefix": "data/in",
    "prefix/": "data/in/",
    "glob": "data/in/*.laz",
    "list": "data/in/list.lst",
    "vpc": "data/in/index.vpc",
}

IS_SOURCE = "{B}/data/in/a.laz is the source: cloudsieve never overwrites its input"
HOLDS = "destination {B}/data/in holds the source {B}/data/in/a.laz: cloudsieve never overwrites its input"
ABOVE = "destination {B}/data holds the source {B}/data/in/a.laz: cloudsieve never overwrites its input"
STORE = "work store {B}/data/in holds the source {B}/data/in/a.laz: cloudsieve never overwrites its input"
STORE_ABOVE = "work store {B}/data holds the source {B}/data/in/a.laz: cloudsieve never overwrites its input"

#: (DST, options, the message): every destination that is, holds or lies in an input ("{B}": the bucket URL)
DESTINATIONS = {
    "the object": ("data/in/a.laz", {}, IS_SOURCE),
    "the prefix as a file": ("data/in", {}, HOLDS),
    "the prefix as tiles": ("data/in", {"tile_size": 500.0}, HOLDS),
    "the prefix/ as tiles": ("data/in/", {"tile_size": 500.0}, HOLDS),
    "the prefix above as tiles": ("data", {"tile_size": 500.0}, ABOVE),
    "the prefix as COPC": ("data/in", {"format": "copc"}, HOLDS),
    "the prefix as the work store": ("out.laz", {"store": "data/in"}, STORE),
    "the prefix above as the work store": ("out.laz", {"store": "data"}, STORE_ABOVE),
}


def _url(bucket: str, path: str) -> str:
    if "{B}" in path:
        return path.replace("{B}", bucket)
    return path if "://" in path else f"{bucket}/{path}"


def _refused(bucket, opts, src, dst, overwrite, options, error=SameSourceDestinationError) -> str:
    options = {k: _url(bucket, v) if k == "store" else v for k, v in options.items()}
    with pytest.raises(error) as exc:
        cloudsieve.simplify(_url(bucket, src), _url(bucket, dst), ratio=0.5, overwrite=overwrite,
                            storage_options=opts, **options)
    return str(exc.value).replace(bucket, "{B}")


@pytest.mark.parametrize("overwrite", [False, True], ids=["no-overwrite", "overwrite"])
@pytest.mark.parametrize("dst_form", list(DESTINATIONS))
@pytest.mark.parametrize("src_form", list(SOURCES))
def test_no_input_is_ever_deleted(inputs, unchanged, src_form, dst_form, overwrite):
    bucket, opts, _ = inputs
    dst, options, message = DESTINATIONS[dst_form]
    assert _refused(bucket, opts, SOURCES[src_form], dst, overwrite, options) == message


#: other ways to name an input: the list or the VPC itself, another name of the protocol, a path with "//",
#: "." or "..", the bucket itself; (SRC, DST, options, the message)
OTHER_NAMES = {
    "the list itself": ("data/in/list.lst", "data/in/list.lst", {"format": "laz"},
                        "{B}/data/in/list.lst is the source: cloudsieve never overwrites its input"),
    "the VPC itself": ("data/in/index.vpc", "data/in/index.vpc", {"format": "laz"},
                       "{B}/data/in/index.vpc is the source: cloudsieve never overwrites its input"),
    "the VPC itself as tiles": ("data/in/index.vpc", "data/in/index.vpc", {"tile_size": 500.0},
                                "{B}/data/in/index.vpc is the source: cloudsieve never overwrites its input"),
    "the list itself as the work store": ("data/in/list.lst", "out.laz", {"store": "data/in/list.lst"},
                                          "{B}/data/in/list.lst is the source: cloudsieve never overwrites its "
                                          "input"),
    "the object as the work store": ("data/in/a.laz", "out.laz", {"store": "data/in/a.laz"}, IS_SOURCE),
    "s3a:// for the object": ("data/in/a.laz", "s3a{B}/data/in/a.laz", {},
                              "s3a{B}/data/in/a.laz is the source: cloudsieve never overwrites its input"),
    "s3a:// for the prefix as tiles": ("data/in/a.laz", "s3a{B}/data/in", {"tile_size": 500.0},
                                       "destination s3a{B}/data/in holds the source {B}/data/in/a.laz: cloudsieve "
                                       "never overwrites its input"),
    "s3a:// for the prefix as the work store": ("data/in/a.laz", "out.laz", {"store": "s3a{B}/data/in"},
                                                "work store s3a{B}/data/in holds the source {B}/data/in/a.laz: "
                                                "cloudsieve never overwrites its input"),
    "// in the object's key": ("data/in/a.laz", "data//in/a.laz", {},
                               "{B}/data//in/a.laz is the source: cloudsieve never overwrites its input"),
    "./ in the prefix as tiles": ("data/in/a.laz", "data/./in", {"tile_size": 500.0},
                                  "destination {B}/data/./in holds the source {B}/data/in/a.laz: cloudsieve never "
                                  "overwrites its input"),
    "../ in the prefix as the work store": ("data/in/a.laz", "out.laz", {"store": "data/x/../in"},
                                            "work store {B}/data/x/../in holds the source {B}/data/in/a.laz: "
                                            "cloudsieve never overwrites its input"),
    "the bucket as tiles": ("data/in/a.laz", "{B}", {"tile_size": 500.0},
                            "destination {B} holds the source {B}/data/in/a.laz: cloudsieve never overwrites its "
                            "input"),
    "the bucket as the work store": ("data/in/a.laz", "out.laz", {"store": "{B}"},
                                     "work store {B} holds the source {B}/data/in/a.laz: cloudsieve never "
                                     "overwrites its input"),
}


@pytest.mark.parametrize("overwrite", [False, True], ids=["no-overwrite", "overwrite"])
@pytest.mark.parametrize("case", list(OTHER_NAMES))
def test_no_other_name_of_an_input_is_written(inputs, unchanged, case, overwrite):
    bucket, opts, _ = inputs
    src, dst, options, message = OTHER_NAMES[case]
    if dst.startswith("s3a{B}"):  # s3a://bucket/...: the same objects as s3://bucket/...
        dst = "s3a://" + bucket[5:] + dst[6:]
    if options.get("store", "").startswith("s3a{B}"):
        options = {**options, "store": "s3a://" + bucket[5:] + options["store"][6:]}
    got = _refused(bucket, opts, src, dst, overwrite, options).replace("s3a://" + bucket[5:], "s3a{B}")
    assert got == message


@pytest.mark.parametrize("overwrite", [False, True], ids=["no-overwrite", "overwrite"])
def test_a_prefix_or_an_object_of_others_is_never_a_work_store(inputs, unchanged, overwrite):
    """Nothing of the run's own there: refused with or without overwrite (a store is created with zarr's
    mode "w", which would delete the prefix's objects)."""
    bucket, opts, _ = inputs
    assert _refused(bucket, opts, "data/in/a.laz", "out.laz", overwrite, {"store": "other"},
                    DestinationExistsError) == (
        "work store {B}/other holds 1 entry (notes.txt) and no cloudsieve point store: cloudsieve replaces only "
        "its own point stores (choose another store)")
    assert _refused(bucket, opts, "data/in/a.laz", "out.laz", overwrite, {"store": "other/notes.txt"},
                    DestinationExistsError) == (
        "work store {B}/other/notes.txt is a file: cloudsieve never replaces a file with a point store (choose "
        "another store)")


def test_ingest_never_replaces_a_prefix_of_others(inputs, unchanged):
    bucket, opts, _ = inputs
    with pytest.raises(DestinationExistsError) as exc:
        cloudsieve.ingest(f"{bucket}/data/in/a.laz", f"{bucket}/other", overwrite=True, storage_options=opts)
    assert str(exc.value).replace(bucket, "{B}") == (
        "{B}/other holds 1 entry (notes.txt) and no cloudsieve point store: cloudsieve replaces only a folder of "
        "its own output (remove it, or choose another name)")
    with pytest.raises(SameSourceDestinationError):
        cloudsieve.ingest(f"{bucket}/data/in/a.laz", f"s3a://{bucket[5:]}/data/in", overwrite=True,
                          storage_options=opts)
