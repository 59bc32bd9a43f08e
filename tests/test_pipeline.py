"""Pipelines: the parser's contract (exact messages) and a real end-to-end run."""

from __future__ import annotations

import json
import shutil

import laspy
import pytest

from cloudsieve.cli import main
from cloudsieve.errors import PipelineError
from cloudsieve.pipeline import load_pipeline, run_pipeline
from conftest import ROOT, shared_file


def write(tmp_path, doc, name="p.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return path


def simple_pipeline(src, dst, **entropy):
    return {
        "pipeline": [
            {"type": "readers.las", "filename": str(src)},
            {"type": "filters.entropy", **entropy},
            {"type": "writers.las", "filename": str(dst)},
        ]
    }


def test_missing_file(tmp_path):
    with pytest.raises(PipelineError, match=r"nope\.json: no such pipeline file"):
        load_pipeline(tmp_path / "nope.json")


def test_invalid_json_names_the_line(tmp_path):
    path = write(tmp_path, '{"pipeline": [\n  {"type": "readers.las",}\n]}')
    with pytest.raises(PipelineError, match=r"p\.json: not valid JSON: .* at line 2"):
        load_pipeline(path)


def test_first_stage_must_be_a_reader(tmp_path):
    path = write(tmp_path, {"pipeline": [{"type": "filters.entropy"}]})
    with pytest.raises(PipelineError, match=r"stage 1 must be a reader .*got 'filters.entropy'"):
        load_pipeline(path)


def test_unknown_stage_type(tmp_path):
    path = write(tmp_path, {"pipeline": [{"type": "readers.las", "filename": "a.las"}, {"type": "filters.smrf"}]})
    with pytest.raises(PipelineError, match=r"stage 2 \(filters.smrf\): unknown stage type"):
        load_pipeline(path)


def test_unknown_option_lists_the_accepted_ones(tmp_path):
    path = write(tmp_path, simple_pipeline("a.las", "b.las", treshold=0.1))
    with pytest.raises(PipelineError, match=r"stage 2 \(filters.entropy\): unknown option\(s\) \['treshold'\]; accepted: .*'threshold'"):
        load_pipeline(path)


def test_entropy_needs_a_writer(tmp_path):
    doc = {"pipeline": [{"type": "readers.las", "filename": "a.las"}, {"type": "filters.entropy", "ratio": 0.5}]}
    with pytest.raises(PipelineError, match=r"filters.entropy needs a writers\.\* stage"):
        load_pipeline(write(tmp_path, doc))


def test_evaluate_needs_a_writer_before_it(tmp_path):
    doc = {"pipeline": [{"type": "readers.las", "filename": "a.las"}, {"type": "evaluate"}]}
    with pytest.raises(PipelineError, match=r"evaluate needs a writer before it"):
        load_pipeline(write(tmp_path, doc))


def test_glob_over_several_files_needs_stem(tmp_path):
    for name in ("a.las", "b.las"):
        (tmp_path / name).write_bytes(b"")
    doc = simple_pipeline(tmp_path / "*.las", tmp_path / "out.las", ratio=0.5)
    with pytest.raises(PipelineError, match=r"must contain \{stem\} or \{name\} because the reader matches 2 files"):
        load_pipeline(write(tmp_path, doc))
    doc = simple_pipeline(tmp_path / "*.las", tmp_path / "out" / "{stem}.laz", ratio=0.5)
    assert [p.rsplit("/", 1)[1] for p in load_pipeline(write(tmp_path, doc)).inputs] == ["a.las", "b.las"]


def test_overrides_and_env_vars(tmp_path, monkeypatch):
    monkeypatch.setenv("SCANS", str(tmp_path))
    doc = simple_pipeline("$SCANS/a.las", "b.las", threshold=0.001)
    p = load_pipeline(write(tmp_path, doc), overrides=["filters.entropy.threshold=0.01", "filters.entropy.method=km"])
    assert p.inputs == [f"{tmp_path}/a.las"]
    entropy = p.stages[0]
    assert entropy["threshold"] == 0.01 and entropy["method"] == "km"
    with pytest.raises(PipelineError, match=r"the pipeline has no stage of type 'writers.ply'"):
        load_pipeline(write(tmp_path, doc), overrides=["writers.ply.filename=x.ply"])


def test_shipped_pipelines_parse(monkeypatch):
    monkeypatch.setenv("CLOUDSIEVE_DATA", str(shared_file("maxplanck.ply").parent))
    for path in sorted((ROOT / "pipelines").glob("*.json")):
        if "batch" in path.name or path.name == "simplify.json":
            continue  # their inputs are placeholders the user supplies
        assert load_pipeline(path).stages, path


def test_cli_check_and_error_exit(tmp_path, capsys):
    src = shared_file("simple.laz")
    path = write(tmp_path, simple_pipeline(src, tmp_path / "out.laz", ratio=0.5))
    assert main(["run", str(path), "--check"]) == 0
    assert "valid; 1 input(s)" in capsys.readouterr().out
    bad = write(tmp_path, {"pipeline": []}, "bad.json")
    assert main(["run", str(bad)]) == 2
    assert "cloudsieve run: error: " in capsys.readouterr().err


def test_run_end_to_end(tmp_path):
    src = tmp_path / "simple.laz"
    shutil.copy(shared_file("simple.laz"), src)
    doc = simple_pipeline(tmp_path / "*.laz", tmp_path / "out" / "{stem}-small.laz", method="km", ratio=0.5, seed=3)
    doc["scheduler"] = "sync"
    results = run_pipeline(load_pipeline(write(tmp_path, doc)))
    out = tmp_path / "out" / "simple-small.laz"
    assert results[0]["output"] == str(out)
    with laspy.open(src) as a, laspy.open(out) as b:
        assert abs(b.header.point_count - a.header.point_count * 0.5) <= 0.01 * a.header.point_count
        assert b.header.point_format.id == a.header.point_format.id


def test_reader_must_match_the_files(tmp_path):
    doc = simple_pipeline(shared_file("bun_zipper.ply"), tmp_path / "out.las", ratio=0.5)
    with pytest.raises(PipelineError, match=r"stage 1 \(readers.las\) cannot read .*bun_zipper.ply: its extension says ply"):
        run_pipeline(load_pipeline(write(tmp_path, doc)))


def test_reader_writer_without_filter_converts(tmp_path):
    src = shared_file("simple.laz")
    doc = {"pipeline": [str(src), {"type": "writers.ply", "filename": str(tmp_path / "simple.ply")}]}
    run_pipeline(load_pipeline(write(tmp_path, doc)))
    from cloudsieve.io import read_cloud

    xyz, attrs = read_cloud(tmp_path / "simple.ply")
    with laspy.open(src) as f:
        las = f.read()
    assert len(xyz) == len(las.points)
    assert (attrs["intensity"] == las.intensity).all()


def test_compare_validates_its_options_once_on_the_command_line_and_in_a_pipeline(tmp_path, monkeypatch, capsys):
    """The CLI validates to size its bar and a pipeline when it is loaded; both then run run_compare, which
    checks no option again."""
    import cloudsieve.params as params
    import cloudsieve.pipeline_load as loader

    calls = []
    real = params.validate

    def counting(command, values, **kw):
        calls.append(command)
        return real(command, values, **kw)

    for module in (params, loader):  # params.options validates through params.validate
        monkeypatch.setattr(module, "validate", counting)
    src = str(shared_file("maxplanck.ply"))
    assert main(["compare", src, "--methods", "random", "--ratio", "0.2", "--no-surface", "--no-progress"]) == 0
    assert "random" in capsys.readouterr().out
    assert calls.count("compare") == 1
    calls.clear()
    doc = {"pipeline": [{"type": "readers.ply", "filename": src},
                        {"type": "compare", "methods": ["random"], "ratio": 0.2, "surface": False}]}
    [entry] = run_pipeline(load_pipeline(write(tmp_path, doc)))
    assert entry["report"]["rows"][0]["method"] == "random"
    assert calls.count("compare") == 1
