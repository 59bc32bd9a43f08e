"""No way to delete, overwrite or write into an input: every form of SRC against every form of DST that could
reach it (the source file, its folder, a folder above it, as a file, tiles, COPC or a work store), with and
without overwrite. Each is refused before any work, and every file under the test's folder keeps its bytes."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys

import pytest

import cloudsieve
from cloudsieve.errors import CloudsieveError, DestinationExistsError, SameSourceDestinationError

from conftest import shared_file


def _tree(root) -> dict:
    """Every file and folder under *root*, with each file's SHA-256."""
    out = {}
    for folder, dirs, files in os.walk(root):
        for d in dirs:
            out[os.path.relpath(os.path.join(folder, d), root)] = "dir"
        for f in files:
            p = os.path.join(folder, f)
            with open(p, "rb") as fh:
                out[os.path.relpath(p, root)] = hashlib.sha256(fh.read()).hexdigest()
    return out


@pytest.fixture
def layout(tmp_path):
    """root/in/{a,b}.laz, root/in/list.lst (relative lines), root/in/index.vpc and root/c.copc.laz."""
    from cloudsieve.io.vpc import describe_tile, write_vpc

    src = tmp_path / "in"
    src.mkdir()
    for name in ("a.laz", "b.laz"):
        shutil.copy(shared_file("simple.laz"), src / name)
    (src / "list.lst").write_text("a.laz\nb.laz\n")
    write_vpc(str(src / "index.vpc"), [describe_tile(str(src / n)) for n in ("a.laz", "b.laz")])
    shutil.copy(shared_file("simple.copc.laz"), tmp_path / "c.copc.laz")
    return tmp_path


SOURCES = {
    "file": "in/a.laz",
    "folder": "in",
    "folder/": "in/",
    "glob": "in/*.laz",
    "list": "in/list.lst",
    "vpc": "in/index.vpc",
}

#: (DST, options): every destination that is, holds or lies in an input
DESTINATIONS = {
    "the file": ("in/a.laz", {}),
    "the folder as a file": ("in", {}),
    "the folder as tiles": ("in", {"tile_size": 500.0}),
    "the folder/ as tiles": ("in/", {"tile_size": 500.0}),
    "the folder above as tiles": (".", {"tile_size": 500.0}),
    "the folder as COPC": ("in", {"format": "copc"}),
    "the folder as the work store": ("out.laz", {"store": "in"}),
    "the folder above as the work store": ("out.laz", {"store": "."}),
}


@pytest.mark.parametrize("overwrite", [False, True], ids=["no-overwrite", "overwrite"])
@pytest.mark.parametrize("dst_form", list(DESTINATIONS))
@pytest.mark.parametrize("src_form", list(SOURCES))
def test_no_input_is_ever_deleted(layout, monkeypatch, src_form, dst_form, overwrite):
    monkeypatch.chdir(layout)
    dst, options = DESTINATIONS[dst_form]
    before = _tree(layout)
    with pytest.raises(CloudsieveError):
        cloudsieve.simplify(SOURCES[src_form], dst, ratio=0.5, overwrite=overwrite, **options)
    assert _tree(layout) == before


@pytest.mark.parametrize("overwrite", [False, True], ids=["no-overwrite", "overwrite"])
def test_a_copc_source_is_never_its_destination(layout, monkeypatch, overwrite):
    monkeypatch.chdir(layout)
    before = _tree(layout)
    with pytest.raises(SameSourceDestinationError):
        cloudsieve.simplify("c.copc.laz", "c.copc.laz", ratio=0.5, overwrite=overwrite)
    with pytest.raises(SameSourceDestinationError):
        cloudsieve.simplify("c.copc.laz", ".", ratio=0.5, tile_size=500.0, overwrite=overwrite)
    assert _tree(layout) == before


@pytest.mark.parametrize("overwrite", [False, True], ids=["no-overwrite", "overwrite"])
@pytest.mark.parametrize("listing", ["in/list.lst", "in/index.vpc"])
def test_a_list_or_a_vpc_is_an_input_too(layout, monkeypatch, listing, overwrite):
    monkeypatch.chdir(layout)
    before = _tree(layout)
    for options, named in (({"format": "laz"}, listing), ({"store": listing}, f"{layout}/{listing}")):
        with pytest.raises(SameSourceDestinationError) as exc:
            cloudsieve.simplify(listing, listing if "format" in options else "o.laz", ratio=0.5,
                                overwrite=overwrite, **options)
        assert str(exc.value) == f"{named} is the source: cloudsieve never overwrites its input"
    assert _tree(layout) == before


def test_the_messages_name_the_input(layout, monkeypatch):
    monkeypatch.chdir(layout)
    with pytest.raises(SameSourceDestinationError) as exc:
        cloudsieve.simplify("in", "in", ratio=0.5, tile_size=500.0, overwrite=True)
    assert str(exc.value) == (f"destination in holds the source {layout}/in/a.laz: "
                              "cloudsieve never overwrites its input")
    with pytest.raises(SameSourceDestinationError) as exc:
        cloudsieve.simplify("in/a.laz", "out.laz", ratio=0.5, store="in", overwrite=True)
    assert str(exc.value) == (f"work store {layout}/in holds the source in/a.laz: "
                              "cloudsieve never overwrites its input")
    (layout / "ee.laz").mkdir()
    (layout / "ee.laz" / "x").write_text("x")
    with pytest.raises(DestinationExistsError) as exc:
        cloudsieve.simplify("in/a.laz", "ee.laz", ratio=0.5, overwrite=True)
    assert str(exc.value) == ("ee.laz is a folder: cloudsieve never replaces a folder with a file "
                              "(remove it, or choose another name)")


def test_the_command_refuses_with_status_2_and_keeps_the_input(layout):
    before = _tree(layout)
    proc = subprocess.run([sys.executable, "-m", "cloudsieve", "simplify", "in/", "in/", "--ratio", "0.5",
                           "--tile-size", "500", "--overwrite"], cwd=layout, capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        f"cloudsieve simplify: error: destination in holds the source {layout}/in/a.laz: "
        "cloudsieve never overwrites its input")
    assert _tree(layout) == before


def test_a_folder_of_other_files_is_never_replaced(layout, monkeypatch):
    """Tiles replace only a folder of their own tiles and index.vpc; a store only a point store."""
    monkeypatch.chdir(layout)
    (layout / "keep").mkdir()
    (layout / "keep" / "notes.txt").write_text("mine")
    before = _tree(layout)
    with pytest.raises(DestinationExistsError) as exc:
        cloudsieve.simplify("in/a.laz", "keep", ratio=0.5, tile_size=500.0, overwrite=True)
    assert str(exc.value) == ("keep holds 1 entry other than its tiles and index.vpc (notes.txt): "
                              "cloudsieve replaces only a folder of its own output (remove it, or choose another name)")
    with pytest.raises(DestinationExistsError) as exc:
        cloudsieve.simplify("in/a.laz", "o.laz", ratio=0.5, store="keep", overwrite=True)
    assert str(exc.value) == (f"work store {layout}/keep holds 1 entry (notes.txt) and no cloudsieve point store: "
                              "cloudsieve replaces only its own point stores (choose another store)")
    with pytest.raises(DestinationExistsError):
        cloudsieve.ingest("in/a.laz", "keep", overwrite=True)
    assert _tree(layout) == before


def test_tiles_replace_their_own_folder(layout, monkeypatch):
    monkeypatch.chdir(layout)
    first = cloudsieve.simplify("in/a.laz", "tiles", ratio=0.5, tile_size=500.0)
    again = cloudsieve.simplify("in/a.laz", "tiles/", ratio=0.2, tile_size=500.0, overwrite=True)
    assert again.kept < first.kept
    assert "index.vpc" in os.listdir(layout / "tiles")
    assert not any(n.endswith(".cloudsieve.zarr") for n in os.listdir(layout) + os.listdir(layout / "tiles"))


def test_tile_checks_run_before_any_work(layout):
    """A tile size too small for the headers' bounds and a file name for a folder of tiles: status 2,
    the option named as its flag, nothing written (no work store, no folder)."""
    before = _tree(layout)
    runs = [
        (["in/a.laz", "t", "--ratio", "0.5", "--tile-size", "1e-9", "--workers", "2"],
         "cloudsieve simplify: error: --tile-size 1e-09 is too small for in/a.laz: coordinates up to 853535 "
         "give tile indices beyond 32 bits (--tile-size must be at least 0.000397)"),
        (["in/a.laz", "x.copc.laz", "--ratio", "0.5", "--tile-size", "500"],
         "cloudsieve simplify: error: x.copc.laz: --tile-size writes a folder of LAZ tiles and index.vpc, and "
         "this name is a COPC file's; give a folder name, or leave out --tile-size for one file"),
        (["in/a.laz", "x.ply", "--ratio", "0.5", "--tile-size", "500"],
         "cloudsieve simplify: error: x.ply: --tile-size writes a folder of LAZ tiles and index.vpc, and "
         "this name is a PLY file's; give a folder name, or leave out --tile-size for one file"),
    ]
    for args, message in runs:
        proc = subprocess.run([sys.executable, "-m", "cloudsieve", "simplify", *args], cwd=layout,
                              capture_output=True, text=True)
        assert (proc.returncode, proc.stderr.strip().splitlines()[-1]) == (2, message)
        assert _tree(layout) == before
