"""Issue 27, item 2: every count a log line prints is the count of what it describes.

Without a terminal each stage logs ``STAGE: N points in S s``: export's N is
the points written (not read), a pipeline's N the points of its inputs, each
counted once (not once per stage). Run as a user runs them, in a subprocess.
"""

from __future__ import annotations

import json
import re
import shutil

import laspy

from conftest import shared_file
from test_ops_progress import cloudsieve, stage_lines


def counts(stderr: str) -> dict[str, int]:
    """stage -> its count, from the progress log lines."""
    out = {}
    for line in stage_lines(stderr):
        m = re.fullmatch(r"INFO cloudsieve\.progress: (.+): ([\d,]+) \w+ in \d+\.\d s", line)
        assert m, line
        out[m.group(1)] = int(m.group(2).replace(",", ""))
    return out


def points_in(path) -> int:
    with laspy.open(path) as f:
        return f.header.point_count


def test_simplify_logs_the_points_it_writes(tmp_path):
    src = shared_file("simple.las")
    proc = cloudsieve(["simplify", src, tmp_path / "o.las", "--ratio", "0.5", "--scheduler", "sync", "--json"],
                      tmp_path)
    assert proc.returncode == 0, proc.stderr
    kept = json.loads(proc.stdout)["kept"]
    assert kept == points_in(tmp_path / "o.las") == 532
    found = counts(proc.stderr)
    assert found["ingest"] == 1_065 and found["export"] == kept


def test_export_with_a_mask_logs_the_points_it_writes(tmp_path):
    src = shared_file("simple.las")
    assert cloudsieve(["simplify", src, tmp_path / "o.las", "--ratio", "0.25", "--scheduler", "sync", "--store",
                       tmp_path / "w.zarr", "--no-progress"], tmp_path).returncode == 0
    proc = cloudsieve(["export", tmp_path / "w.zarr", tmp_path / "e.las", "--mask", "simplify/keep"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert counts(proc.stderr) == {f"export {tmp_path / 'e.las'}": 266} and points_in(tmp_path / "e.las") == 266


def _tiles(tmp_path, n=3):
    folder = tmp_path / "tiles"
    folder.mkdir()
    for i in range(n):
        shutil.copy(shared_file("simple.las"), folder / f"t{i}.las")
    return folder


def _pipeline(tmp_path, stages):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"scheduler": "sync", "pipeline": [
        {"type": "readers.las", "filename": str(tmp_path / "tiles" / "*.las")}, *stages]}))
    return path


def test_a_pipeline_over_several_files_logs_their_points_once(tmp_path):
    _tiles(tmp_path)
    p = _pipeline(tmp_path, [{"type": "filters.entropy", "ratio": 0.5},
                             {"type": "writers.las", "filename": str(tmp_path / "out" / "{stem}.las")}])
    proc = cloudsieve(["run", p], tmp_path)
    assert proc.returncode == 0, proc.stderr
    found = counts(proc.stderr)
    assert found["pipeline"] == 3 * 1_065
    assert [points_in(tmp_path / "out" / f"t{i}.las") for i in range(3)] == [532] * 3
    exports = [line for line in stage_lines(proc.stderr) if ": export: " in line or "progress: export:" in line]
    assert len(exports) == 3 and all(" 532 points " in line for line in exports)


def test_a_conversion_pipeline_logs_its_points_once(tmp_path):
    _tiles(tmp_path, 2)
    p = _pipeline(tmp_path, [{"type": "writers.las", "filename": str(tmp_path / "out" / "{stem}.laz")}])
    proc = cloudsieve(["run", p], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert counts(proc.stderr) == {"pipeline": 2 * 1_065}
