"""The default rule: eliminate with a ratio or count, threshold with a threshold alone, an error with neither.

Resolved once in :func:`cloudsieve.params.validate`; the CLI, the pipelines
and the API give the same answer, the resolved rule is what a work store records.
"""

from __future__ import annotations

import json
import os

import pytest

import cloudsieve
from cloudsieve import params
from cloudsieve.cli import main
from cloudsieve.engine import workstore
from cloudsieve.errors import InputNotFoundError, InvalidParameterError, PipelineError
from cloudsieve.pipeline import load_pipeline
from cloudsieve.store import PointStore
from engine_data import plane, write_laz

WHY = "(the default rule, eliminate, keeps exactly that many points)"
API = "{} needs ratio=R or count=N " + WHY + ", or threshold=S for the paper's threshold rule"
CLI = "{} needs --ratio R or --count N " + WHY + ", or --threshold S for the paper's threshold rule"


# ----------------------------------------------------------------- the resolution, in params


@pytest.mark.parametrize("given, rule, threshold", [
    ({"ratio": 0.5}, "eliminate", 1e-3),
    ({"count": 10}, "eliminate", 1e-3),
    ({"threshold": 0.01}, "threshold", 0.01),
    ({"rule": "iterative"}, "iterative", 1e-3),  # an explicit rule as before: S = 1e-3 when not given
    ({"rule": "iterative", "threshold": 0.01, "ratio": 0.5}, "iterative", 0.01),
    ({"rule": "target", "count": 10}, "target", 1e-3),
    ({"rule": "eliminate", "ratio": 0.5, "threshold": 0.01}, "eliminate", 0.01),  # explicit: accepted as before
])
def test_the_rule_is_resolved_once_in_validate(given, rule, threshold):
    out = params.validate("simplify", given)
    assert (out["rule"], out["threshold"]) == (rule, threshold)
    assert params.validate("simplify", out) == out  # validating the result gives it back (demo, pipelines)
    record = params.run_record(out)
    assert (record["rule"], record["threshold"]) == (rule, threshold)
    cmp = params.validate("compare", {k: v for k, v in given.items()})
    assert (cmp["rule"], cmp["threshold"]) == ([rule], threshold)


def test_without_ratio_count_or_threshold_validate_says_what_is_needed():
    for command in ("simplify", "compare"):
        with pytest.raises(InvalidParameterError) as exc:
            params.validate(command, {"seed": 3})
        assert str(exc.value) == API.format(f"cloudsieve.{command}")
    with pytest.raises(InvalidParameterError) as exc:
        params.validate("simplify", {}, caller="cloudsieve simplify")
    assert str(exc.value) == API.format("cloudsieve simplify")
    # compare's baselines alone need no rule (compare asks for the count itself)
    assert params.validate("compare", {"methods": "voxel,poisson"})["rule"] == ["eliminate"]


def test_a_threshold_beside_a_ratio_without_a_rule_is_refused():
    with pytest.raises(InvalidParameterError) as exc:
        params.validate("simplify", {"ratio": 0.5, "threshold": 0.01})
    assert str(exc.value) == (
        "threshold=0.01 is the S of the paper's rules threshold and iterative, but with ratio=0.5 the default "
        "rule is eliminate, which takes no threshold: add rule='iterative' to use both, or leave the threshold out")


# ----------------------------------------------------------------- the API


def test_api_simplify_and_compare_need_a_ratio_count_or_threshold_and_create_nothing(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(2_000, side=20.0))
    before = sorted(os.listdir(tmp_path))
    with pytest.raises(InvalidParameterError) as exc:
        cloudsieve.simplify(src, tmp_path / "o.laz", method="fcm")
    assert str(exc.value) == API.format("cloudsieve.simplify")
    with pytest.raises(InvalidParameterError) as exc:
        cloudsieve.compare(src, report_dir=tmp_path / "cmp")
    assert str(exc.value) == API.format("cloudsieve.compare")
    assert sorted(os.listdir(tmp_path)) == before
    missing = tmp_path / "missing.laz"  # valid options: the API goes on and fails on the source
    for kw in ({"ratio": 0.5}, {"count": 10}, {"threshold": 0.01}):
        with pytest.raises(InputNotFoundError):
            cloudsieve.simplify(missing, tmp_path / "o.laz", **kw)
        with pytest.raises(InputNotFoundError):
            cloudsieve.compare(missing, **kw)


def test_the_resolved_rule_is_recorded_and_the_same_call_resumes(tmp_path):
    src = write_laz(tmp_path / "p.laz", plane(4_000, side=40.0))
    store = tmp_path / "w.zarr"
    kw = dict(cell_size=1_000, chunk_size=2_000, scheduler="sync", store=store)
    a = cloudsieve.simplify(src, tmp_path / "a.laz", ratio=0.25, **kw)
    assert a.kept == 1_000  # eliminate: exactly the count
    recorded = PointStore.open(str(store)).attrs[workstore.SIMPLIFY_ATTR]["params"]
    assert (recorded["rule"], recorded["threshold"], recorded["ratio"]) == ("eliminate", 1e-3, 0.25)
    b = cloudsieve.simplify(src, tmp_path / "b.laz", ratio=0.25, resume=True, **kw)
    assert b.cells_computed == 0 and b.cells_reused == b.cells
    assert (tmp_path / "a.laz").read_bytes() == (tmp_path / "b.laz").read_bytes()
    c = cloudsieve.simplify(src, tmp_path / "c.laz", ratio=0.25, rule="eliminate", resume=True, **kw)
    assert c.cells_computed == 0  # the explicit rule is the same run
    d = cloudsieve.simplify(src, tmp_path / "d.laz", threshold=0.01, overwrite=True, **kw)
    recorded = PointStore.open(str(store)).attrs[workstore.SIMPLIFY_ATTR]["params"]
    assert (recorded["rule"], recorded["threshold"]) == ("threshold", 0.01) and d.kept < d.points_in


# ----------------------------------------------------------------- the command line


def test_cli_exits_2_with_the_message_and_creates_nothing(tmp_path, capsys):
    src = write_laz(tmp_path / "p.laz", plane(2_000, side=20.0))
    before = sorted(os.listdir(tmp_path))
    for argv, command in ([["simplify", str(src), str(tmp_path / "o.laz")], "simplify"],
                          [["simplify", str(src), str(tmp_path / "o.laz"), "--method", "fcm", "--seed", "2"],
                           "simplify"],
                          [["compare", str(src), "--report", str(tmp_path / "cmp")], "compare"]):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.strip() == f"cloudsieve {command}: error: " + CLI.format(f"cloudsieve {command}")
    assert main(["simplify", str(src), str(tmp_path / "o.laz"), "--count", "5", "--threshold", "0.1"]) == 2
    assert capsys.readouterr().err.strip() == (
        "cloudsieve simplify: error: --threshold 0.1 is the S of the paper's rules threshold and iterative, but "
        "with --count 5 the default rule is eliminate, which takes no threshold: add --rule iterative to use "
        "both, or leave the threshold out")
    assert sorted(os.listdir(tmp_path)) == before


@pytest.mark.parametrize("args, rule", [(["--ratio", "0.5"], "eliminate"), (["--count", "700"], "eliminate"),
                                        (["--threshold", "0.01"], "threshold")])
def test_cli_resolves_the_rule(tmp_path, capsys, args, rule):
    src = write_laz(tmp_path / "p.laz", plane(2_000, side=20.0))
    store = tmp_path / "w.zarr"
    assert main(["simplify", str(src), str(tmp_path / "o.laz"), "--store", str(store), "--scheduler", "sync",
                 "--no-progress", "--json", *args]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert PointStore.open(str(store)).attrs[workstore.SIMPLIFY_ATTR]["params"]["rule"] == rule
    if args[0] == "--count":
        assert summary["kept"] == 700


def test_help_says_the_default_and_what_it_needs(capsys):
    for command in ("simplify", "compare"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "default: eliminate" in text and "--ratio or --count" in text, command
        assert "--threshold alone: threshold" in text, command


# ----------------------------------------------------------------- pipelines


def _doc(tmp_path, stage: dict) -> dict:
    return {"pipeline": [{"type": "readers.las", "filename": str(tmp_path / "in.laz")}, stage,
                         {"type": "writers.las", "filename": str(tmp_path / "out.laz")}]}


def test_pipeline_stage_resolves_the_rule_or_is_refused_when_loaded(tmp_path, capsys):
    load_pipeline(_doc(tmp_path, {"type": "filters.entropy", "ratio": 0.5}))
    load_pipeline(_doc(tmp_path, {"type": "filters.entropy", "count": 10}))
    load_pipeline(_doc(tmp_path, {"type": "filters.entropy", "threshold": 0.01}))
    with pytest.raises(PipelineError) as exc:
        load_pipeline(_doc(tmp_path, {"type": "filters.entropy", "method": "km"}))
    assert str(exc.value) == "<pipeline>: stage 2 (filters.entropy): " + API.format("filters.entropy")
    compare = {"pipeline": [{"type": "readers.las", "filename": str(tmp_path / "in.laz")}, {"type": "compare"}]}
    with pytest.raises(PipelineError) as exc:
        load_pipeline(compare)
    assert str(exc.value) == "<pipeline>: stage 2 (compare): " + API.format("compare")
    path = tmp_path / "p.json"
    path.write_text(json.dumps(_doc(tmp_path, {"type": "filters.entropy"})))
    assert main(["run", str(path)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"cloudsieve run: error: {path}: stage 2 (filters.entropy): filters.entropy needs \"ratio\" or \"count\" "
        f"{WHY}, or \"threshold\" for the paper's threshold rule")
    assert sorted(os.listdir(tmp_path)) == ["p.json"]


def test_pipeline_runs_with_the_default_rule(tmp_path):
    src = write_laz(tmp_path / "in.laz", plane(2_000, side=20.0))
    doc = _doc(tmp_path, {"type": "filters.entropy", "count": 500, "scheduler": "sync"})
    (entry,) = cloudsieve.run_pipeline(load_pipeline(doc))
    assert entry["input"] == str(src) and entry["summary"].kept == 500


def test_compare_default_table_is_eliminate_and_the_baselines(tmp_path, capsys):
    src = write_laz(tmp_path / "p.laz", plane(2_000, side=20.0))
    result = cloudsieve.compare(src, count=500, surface=False)
    assert [r["method"] for r in result["rows"]] == ["eliminate", "random", "voxel", "poisson", "fps"]
    assert result["rule"] == "eliminate" and result["rows"][0]["kept"] == 500
    assert main(["compare", str(src), "--count", "500", "--no-surface", "--no-progress", "--methods", "km,voxel"]) == 0
    out = capsys.readouterr().out
    assert "rule `eliminate`" in out and "| eliminate | 500 |" in out and "| voxel |" in out
