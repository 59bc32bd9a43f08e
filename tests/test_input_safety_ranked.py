"""No ranked or nested output reaches its input: ``export FILE DST --keep-rank N``, ``export FILE DST.copc.laz``,
``simplify --rank`` to COPC (its levels are written elsewhere first) and nested outputs (a level's path can be
the source), each against DST = the source (as given, ``./``-relative, absolute) and a folder holding it, with and
without overwrite: refused before any work, and every file under the test's folder keeps its bytes."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

import cloudsieve
from cloudsieve.errors import SameSourceDestinationError
from cloudsieve.io.rank import cut_rank
from cloudsieve.store.copc import file_to_copc

from conftest import shared_file
from test_input_safety import _tree


@pytest.fixture
def ranked(tmp_path, monkeypatch):
    """in/r.laz (ranked), in/r.copc.laz (ranked COPC), in/scan-0.2.laz (a plain file); cwd the test's folder."""
    (tmp_path / "in").mkdir()
    cloudsieve.simplify(shared_file("autzen_trim.laz"), tmp_path / "in" / "r.laz", ratio=0.05, rank=True)
    file_to_copc(str(tmp_path / "in" / "r.laz"), str(tmp_path / "in" / "r.copc.laz"))
    shutil.copy(shared_file("simple.laz"), tmp_path / "in" / "scan-0.2.laz")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _forms(name: str, root) -> dict:
    return {"as given": f"in/{name}", "./": f"./in/{name}", "absolute": str(root / "in" / name), "its folder": "in"}


WRITERS = {
    "export --keep-rank": lambda src, dst, ow: cut_rank(src, dst, 10, overwrite=ow),
    "export to COPC": lambda src, dst, ow: file_to_copc(src, dst, overwrite=ow),
    "simplify --rank to COPC": lambda src, dst, ow: cloudsieve.simplify(src, dst, ratio=0.5, rank=True, overwrite=ow),
}
SOURCE_OF = {"export --keep-rank": "r.laz", "export to COPC": "r.copc.laz", "simplify --rank to COPC": "r.copc.laz"}


@pytest.mark.parametrize("overwrite", [False, True])
@pytest.mark.parametrize("form", ["as given", "./", "absolute", "its folder"])
@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_ranked_output_never_replaces_its_source(ranked, writer, form, overwrite):
    before = _tree(ranked)
    name = SOURCE_OF[writer]
    with pytest.raises(SameSourceDestinationError, match="cloudsieve never overwrites its input"):
        WRITERS[writer](f"in/{name}", _forms(name, ranked)[form], overwrite)
    assert _tree(ranked) == before


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_nested_level_is_never_the_source(ranked, overwrite):
    """``scan.laz`` with ratios 0.5 and 0.2 names its second output ``scan-0.2.laz``: here the source."""
    before = _tree(ranked)
    with pytest.raises(SameSourceDestinationError, match="in/scan-0.2.laz is the source"):
        cloudsieve.simplify("in/scan-0.2.laz", "in/scan.laz", ratio=[0.5, 0.2], overwrite=overwrite)
    assert _tree(ranked) == before


def test_the_command_exits_2_and_keeps_the_ranked_source(ranked):
    before = _tree(ranked)
    for args in (["export", "in/r.laz", "./in/r.laz", "--keep-rank", "10", "--overwrite"],
                 ["export", "in/r.copc.laz", "in/r.copc.laz", "--overwrite"],
                 ["simplify", "in/r.copc.laz", "in/r.copc.laz", "--ratio", "0.5", "--rank", "--overwrite"]):
        p = subprocess.run([sys.executable, "-m", "cloudsieve", *args], capture_output=True, text=True, timeout=300)
        assert p.returncode == 2, (args, p.stderr)
        assert "never overwrites its input" in p.stderr and "Traceback" not in p.stderr
    assert _tree(ranked) == before  # no temporary file left either
