"""What a first-time user meets: help and README agree with the commands (issue 48, item 10).

``--format copc`` as README lists it, COPC and the list file's relative paths
in ``--help``, ``info`` on the many-file sources ``simplify`` reads, and
README's Python snippet running without a warning.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import laspy
import numpy as np
import pytest
from conftest import ROOT, shared_file
from tiles_data import cut_tiles

from cloudsieve.cli import build_parser, main
from cloudsieve.io.vpc import describe_tile, write_vpc
from cloudsieve.store import ingest

README = (ROOT / "README.md").read_text(encoding="utf-8")
COMMANDS = next(a for a in build_parser()._actions if hasattr(a, "choices") and isinstance(a.choices, dict)).choices
CRS = "NAD_1983_HARN_Lambert_Conformal_Conic"


def run(argv, capsys):
    """(exit code, stdout, stderr) of ``cloudsieve ARGV`` in this process."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def words(text: str) -> str:
    return " ".join(text.split())


def is_copc(path) -> bool:
    with laspy.CopcReader.open(str(path)) as reader:  # raises on a LAS/LAZ file that is not COPC
        return reader.header.point_count > 0


# ---------------------------------------------------------------- --format copc


def test_format_copc_writes_copc_whatever_the_name(tmp_path, capsys):
    src = shared_file("simple.laz")
    rc, _, err = run(["simplify", src, tmp_path / "named.copc.laz", "--ratio", "0.5", "--no-progress"], capsys)
    assert rc == 0, err
    want = laspy.read(str(tmp_path / "named.copc.laz")).points.array
    for name in ("asked.copc.laz", "asked.laz"):
        rc, _, err = run(["simplify", src, tmp_path / name, "--ratio", "0.5", "--format", "copc", "--no-progress"],
                         capsys)
        assert rc == 0, err
        assert is_copc(tmp_path / name)
        np.testing.assert_array_equal(laspy.read(str(tmp_path / name)).points.array, want)  # the same file's points
    store = ingest(src, tmp_path / "s.zarr")
    rc, _, err = run(["export", store.path, tmp_path / "exported.laz", "--format", "copc", "--no-progress"], capsys)
    assert rc == 0, err
    assert is_copc(tmp_path / "exported.laz") and laspy.open(str(tmp_path / "exported.laz")).header.point_count == 1065
    rc, _, err = run(["simplify", src, tmp_path / "o.e57", "--ratio", "0.5", "--format", "e57"], capsys)
    assert rc == 2 and err.splitlines()[-1] == (
        "cloudsieve simplify: error: --format must be one of las, laz, copc, ply, xyz, got 'e57'")


# ---------------------------------------------------------------- help and README


def test_help_and_readme_name_copc_and_where_list_paths_start():
    for command in ("simplify", "ingest", "info"):
        src = words(COMMANDS[command].format_help())
        assert "a list file (.lst: one path per line, relative to the list's folder)" in src, command
    assert "output file (LAS/LAZ/COPC (.copc.laz)/PLY/XYZ, by extension or --format)" in words(
        COMMANDS["simplify"].format_help())
    assert "output file (.las, .laz, .copc.laz, .ply, .xyz/.txt/.csv/.pts; or --format)" in words(
        COMMANDS["export"].format_help())
    assert "--format {las,laz,copc,ply,xyz}" in COMMANDS["simplify"].format_help()
    text = words(README)
    assert ("Every command has `--help`; DST's extension (LAS, LAZ, COPC `.copc.laz`, PLY, XYZ) or `--format` "
            "(`--format copc` writes COPC under any name) sets the output format.") in text
    assert "a list file (`.lst`, one path a line, relative to the list's folder)" in text
    assert "`info` lists them, one line a file, and the total." in text


# ---------------------------------------------------------------- info on many files


@pytest.fixture
def tiles(tmp_path):
    return cut_tiles(shared_file("autzen_trim.laz"), tmp_path / "tiles")


def file_line(path) -> str:
    """The line ``info`` prints for a tile, from laspy's header (scale 0.01: two decimals)."""
    h = laspy.open(str(path)).header
    ranges = "".join(f", {a} {lo:.2f} .. {hi:.2f}" for a, lo, hi in zip("xyz", h.mins, h.maxs))
    return f"  {path}: laz, {h.point_count:,} points{ranges}, CRS {CRS}"


def test_info_lists_the_files_of_a_directory_glob_list_and_vpc(tiles, tmp_path, capsys, monkeypatch):
    folder = tiles[0].parent
    total = "  total: 4 files, 110,000 points, x 636001.76 .. 637179.22, y 848935.20 .. 849497.90, z 406.26 .. 520.51"
    rc, out, err = run(["info", folder], capsys)
    assert rc == 0 and err == ""
    assert out.splitlines() == [f"{folder}: 4 files read as one cloud", *map(file_line, tiles), total]
    rc, out, _ = run(["info", folder / "*_1.laz"], capsys)
    assert rc == 0
    two = [tiles[1], tiles[3]]
    counts = [laspy.open(str(p)).header.point_count for p in two]
    assert out.splitlines()[:3] == [f"{folder}/*_1.laz: 2 files read as one cloud", *map(file_line, two)]
    assert out.splitlines()[3].startswith(f"  total: 2 files, {sum(counts):,} points, x ")
    # a list file's paths start at its own folder, wherever the command runs
    (tmp_path / "lists").mkdir()
    (tmp_path / "elsewhere").mkdir()
    lst = tmp_path / "lists" / "tiles.lst"
    lst.write_text("# two tiles, last first\n../tiles/autzen_trim_1_1.laz\n\n../tiles/autzen_trim_0_0.laz\n")
    monkeypatch.chdir(tmp_path / "elsewhere")
    rc, out, _ = run(["info", lst], capsys)
    assert rc == 0 and out.splitlines()[1:3] == [file_line(tiles[3]), file_line(tiles[0])]
    vpc = tmp_path / "all.vpc"
    write_vpc(vpc, [describe_tile(p) for p in reversed(tiles)])
    rc, out, _ = run(["info", vpc], capsys)
    assert rc == 0 and out.splitlines() == [f"{vpc}: 4 files read as one cloud", *map(file_line, reversed(tiles)),
                                            total]


def test_info_json_of_many_files_is_each_files_info_and_the_total(tiles, capsys):
    folder = tiles[0].parent
    rc, out, _ = run(["info", folder, "--json"], capsys)
    assert rc == 0
    doc = json.loads(out)
    assert list(doc) == ["path", "kind", "files", "total"] and doc["kind"] == "files" and doc["path"] == str(folder)
    singles = []
    for p in tiles:
        rc, one, _ = run(["info", p, "--json"], capsys)
        singles.append(json.loads(one))
    assert doc["files"] == singles  # each entry as `info FILE --json` prints it
    headers = [laspy.open(str(p)).header for p in tiles]
    assert doc["total"] == {"files": 4, "count": 110_000,
                            "bounds": [np.min([h.mins for h in headers], axis=0).tolist(),
                                       np.max([h.maxs for h in headers], axis=0).tolist()]}


def test_info_refuses_an_empty_folder_and_a_glob_of_nothing(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    rc, out, err = run(["info", tmp_path / "empty"], capsys)
    assert (rc, out) == (2, "") and err == (f"cloudsieve info: error: {tmp_path / 'empty'} is a directory, not a point "
                                            f"cloud file or point store, and holds no LAS/LAZ file to read as one "
                                            f"cloud\n")
    rc, out, err = run(["info", tmp_path / "*.laz"], capsys)
    assert (rc, out) == (2, "") and err == f"cloudsieve info: error: {tmp_path}/*.laz: the pattern matches no file\n"


# ---------------------------------------------------------------- README's Python snippet


def test_readmes_python_snippet_runs_without_a_warning(tmp_path):
    [code] = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert '"scan.laz"' in code and '"bun_zipper.ply"' in code
    code = code.replace('"scan.laz"', repr(str(shared_file("simple.laz"))))  # the small scan: a short evaluate
    code = code.replace('"bun_zipper.ply"', repr(str(shared_file("bun_zipper.ply"))))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-W", "always", "-c", code], cwd=tmp_path, env=env, capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # no warning, no log line
    rms, share = (float(v) for v in done.stdout.split())
    assert 0 < rms < 5 and 0 < share <= 1
    assert sorted(os.listdir(tmp_path)) == ["report", "small.laz"]
