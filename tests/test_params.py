"""params.py: one spec of every option; the CLI, the pipelines and the API accept and refuse the same values."""

from __future__ import annotations

import json
import math
import socket
from pathlib import Path

import pytest

import cloudsieve
from cloudsieve import params
from cloudsieve.cli import build_parser, main
from cloudsieve.errors import (
    CloudsieveError,
    InputNotFoundError,
    InvalidParameterError,
    PipelineError,
    SchedulerUnreachableError,
)
from cloudsieve.pipeline import load_pipeline
from cloudsieve.scheduler import check_scheduler

# ----------------------------------------------------------------- the table of good and bad values per type


def good_and_bad(option: params.Option, command: str) -> tuple[list, list]:
    """Values every interface must accept / refuse for *option*, from its type and range."""
    k, optional = option.kind, option.default is None
    if k == params.INT:
        low = {"cluster_size": 6, "cell_size": 400}.get(option.name, int(option.low))  # >= k_min + 2, >= cluster_size
        good, bad = [low, low + 2, float(low + 2)], [int(option.low) - 1, low + 0.5, str(low), True]
    elif k == params.FLOAT and option.high is not None:
        good = [option.high, (option.low + option.high) / 2]
        bad = [option.low, option.high + 0.5, math.nan, math.inf, str(option.high), True]
    elif k == params.FLOAT:
        low = option.low + 0.5 if option.low_open else option.low
        good, bad = [low, low + 2.5, int(low) + 3], [option.low - 1, math.nan, math.inf, "1", True]
        if option.low_open:
            bad.append(option.low)
    elif k == params.BOOL:
        good, bad = [True, False], ["yes", 1, None]
    elif k in (params.CHOICE, params.FORMAT):
        good, bad = list(option.choices), ["nope", 1]
        if k == params.FORMAT:
            good.append(option.choices[0].upper())
    elif k == params.CHOICES:
        c = option.choices
        good, bad = [c[0], list(c[:2]), ",".join(c[:2])], ["nope", 3, [c[0], "nope"], [c[0], 3]]
    elif k in (params.PATH, params.TEXT):
        good, bad = ["some/where", "x"], [3, ""]
        if k == params.PATH:
            good.append(Path("some/where"))
    elif k == params.SIZE:
        good, bad = [1, "2GB", "auto"], [0, "lots", 2.5]
    elif k == params.JSON:
        good, bad = [{}, {"anon": True}, '{"anon": true}'], ["{nope", "[1]", 3]
    elif k == params.CLASSES:
        good, bad = ["2", "2,9", [0, 255], (7,)], ["", "x", "256", [-1], [2.5], True, 3]
    elif k == params.CLASS_RATIOS:
        good, bad = ["5=0.1", "5=0.1,2=1", {5: 0.5}, [[2, 1.0]]], ["", "5", "5=0", "5=1.5", "256=0.5", {5: "x"},
                                                                   "5=0.1,5=0.2", 3]
    else:  # scheduler
        good, bad = ["sync", "threads", "processes", "tcp://127.0.0.1:1"], ["fast", "tcp://nohost", 3]
    (good if optional else bad).append(None)
    return good, bad


def context(command: str, name: str, value) -> dict:
    """Other options a value needs to be valid together (rule target needs a ratio).

    simplify and compare need a rule that can run: the default, eliminate,
    needs a ratio or a count, so the other options are walked with the
    paper's rule iterative (which needs neither); rank and max_gap, eliminate's
    only, with a ratio.
    """
    if command == "simplify" and name == "rule" and (value is None or value in params.TARGET_RULES):
        return {"ratio": 0.5}
    if command == "compare" and name == "rule" and value is None:
        return {"ratio": 0.5}
    if command not in ("simplify", "compare") or name == "rule":
        return {}
    if name in ("ratio", "count", "threshold") and value is not None:
        return {}
    if name in ("keep_class", "class_ratio") or (name == "rank" and value is True) or (
            name == "max_gap" and value is not None):  # the eliminate rule's
        return {"ratio": 0.5}
    if name == "density" and value is not None:  # instead of a ratio: the default rule
        return {}
    if name == "density_cell" and value is not None:  # the areas of density
        return {"density": 100.0}
    if name == "density_3d" and value:  # density per cubic unit
        return {"density": 1.0}
    return {"rule": "iterative"}


# ----------------------------------------------------------------- the three ways in


def api(command, tmp_path, values) -> str | None:
    """None when the API accepted the options (it then fails on the missing source), else the message."""
    missing = tmp_path / "missing.laz"
    calls = {
        "simplify": lambda: cloudsieve.simplify(missing, tmp_path / "out.laz", **values),
        "evaluate": lambda: cloudsieve.evaluate(missing, missing, **values),
        "compare": lambda: cloudsieve.compare(missing, **values),
        "ingest": lambda: params.validate("ingest", values),  # the CLI validates for ingest and export
        "export": lambda: params.validate("export", values),
    }
    try:
        calls[command]()
    except InputNotFoundError:
        return None
    except InvalidParameterError as exc:
        return str(exc)
    if command in ("ingest", "export"):
        return None
    raise AssertionError(f"{command} {values} ran")  # pragma: no cover


def cli_args(option: params.Option, value) -> list[str] | None:
    """The command-line form of *value*, or None when the CLI cannot express it (it parses text)."""
    k = option.kind
    if k == params.BOOL:
        if not isinstance(value, bool):
            return None
        return [option.flag] if value != option.default else []
    if value is None or isinstance(value, (bool, Path)):
        return None
    if k in (params.INT, params.FLOAT) and isinstance(value, (int, float)):
        return [option.flag, str(value)]
    if k == params.SIZE and isinstance(value, (int, str)):
        return [option.flag, str(value)]
    if k == params.CHOICES and isinstance(value, list) and all(isinstance(v, str) for v in value):
        return [option.flag, ",".join(value)]
    if isinstance(value, str) and k not in (params.INT, params.FLOAT, params.SIZE):
        return [option.flag, value]
    return None


def cli(command, tmp_path, args, capsys) -> bool:
    """Whether the CLI accepted the options (it then fails on the missing source)."""
    missing = str(tmp_path / "missing.laz")
    positional = {"simplify": [missing, str(tmp_path / "out.laz")], "evaluate": [missing, missing],
                  "compare": [missing], "ingest": [missing, str(tmp_path / "s.zarr")],
                  "export": [missing, str(tmp_path / "out.laz")]}[command]
    capsys.readouterr()
    try:
        rc = main([command, *positional, *args])
    except SystemExit as exc:  # argparse: not a number
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2, err
    return "no such file" in err or "input not found" in err or "no such point store" in err


def pipeline(command, tmp_path, values) -> str | None:
    """None when the pipeline parser accepted the options, else the message after the stage label."""
    reader = {"type": "readers.las", "filename": str(tmp_path / "missing.laz")}
    writer = {"type": "writers.las", "filename": str(tmp_path / "out.laz")}
    if command == "simplify":
        doc = {"pipeline": [reader, {"type": "filters.entropy", **values}, writer]}
    elif command == "evaluate":
        doc = {"pipeline": [reader, {"type": "filters.entropy", "ratio": 0.5}, writer, {"type": "evaluate", **values}]}
    else:
        doc = {"pipeline": [reader, {"type": "compare", **values}]}
    try:
        load_pipeline(json.loads(json.dumps(doc)))
    except PipelineError as exc:
        return str(exc).split("): ", 1)[1]
    return None


# ----------------------------------------------------------------- the walk


CASES = [
    (command, name)
    for command in ("simplify", "evaluate", "compare", "ingest", "export")
    for name in params.COMMANDS[command]
]


@pytest.mark.parametrize("command, name", CASES, ids=[f"{c}-{n}" for c, n in CASES])
def test_every_option_is_accepted_and_refused_alike_everywhere(command, name, tmp_path, capsys):
    option = params.COMMANDS[command][name]
    good, bad = good_and_bad(option, command)
    in_pipeline = command in ("simplify", "evaluate", "compare") and not (
        command == "simplify" and name in ("format", "overwrite")) and (  # the writer's options
        name != "drop_invalid")  # the reader's option (test_pipeline_reader_takes_drop_invalid)
    for expected, values in [(True, good), (False, bad)]:
        for value in values:
            options = {name: value, **context(command, name, value)}
            message = api(command, tmp_path, options)
            assert (message is None) == expected, f"API {command} {name}={value!r}: {message}"
            if not expected:
                assert name.rstrip("s") in message, message
            args = cli_args(option, value)
            if args is not None:
                extra = [a for k, v in context(command, name, value).items()
                         for a in cli_args(params.OPTIONS[k], v)]
                assert cli(command, tmp_path, [*args, *extra], capsys) == expected, f"CLI {command} {args}"
            if in_pipeline and not isinstance(value, Path):
                assert pipeline(command, tmp_path, options) == message, f"pipeline {command} {name}={value!r}"


def test_every_option_has_help_and_a_flag_named_after_it():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    for command in ("simplify", "evaluate", "compare", "ingest", "export"):
        flags = {f: a.dest for a in sub[command]._actions for f in a.option_strings}
        for name, option in params.COMMANDS[command].items():
            assert option.help, name
            assert option.flag == ("--no-" if option.kind == params.BOOL and option.default is True else "--") + \
                name.replace("_", "-")
            for flag in (option.flag, *option.aliases):
                assert flags[flag] == name, (command, flag)


def test_old_flags_are_aliases():
    parser = build_parser()
    args = parser.parse_args(["evaluate", "a.laz", "b.laz", "--report", "r", "--force"])
    assert args.report_dir == "r" and args.strict is False
    args = parser.parse_args(["compare", "a.laz", "--report", "r"])
    assert args.report_dir == "r"
    args = parser.parse_args(["simplify", "a.laz", "b.laz", "--halo-context"])
    assert args.halo_context is True


# ----------------------------------------------------------------- ranges agree everywhere


@pytest.mark.parametrize("value", [0, 1.5, -0.5])
def test_ratio_is_refused_outside_0_1_by_every_api(tmp_path, value):
    message = f"ratio must be a number in (0, 1], got {float(value)!r}"
    src = tmp_path / "missing.laz"
    with pytest.raises(InvalidParameterError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        cloudsieve.simplify(src, tmp_path / "o.laz", ratio=value)
    with pytest.raises(InvalidParameterError) as exc:
        cloudsieve.compare(src, ratio=value)
    assert str(exc.value) == message


def test_count_is_an_integer_at_least_1_in_the_api(tmp_path):
    for value in (0, -3, 2.5):
        with pytest.raises(InvalidParameterError) as exc:
            cloudsieve.simplify(tmp_path / "missing.laz", tmp_path / "o.laz", count=value)
        assert str(exc.value) == f"count must be an integer >= 1, got {value!r}"
    assert params.validate("simplify", {"count": 1e6})["count"] == 1_000_000  # JSON's 1e6


def test_cluster_size_is_at_least_k_min_plus_2():
    with pytest.raises(InvalidParameterError) as exc:
        params.validate("simplify", {"cluster_size": 11, "k_min": 10, "rule": "iterative"})
    assert str(exc.value) == "cluster_size=11 is too small: a cluster needs at least k_min+2=12 points"
    assert params.validate("simplify", {"cluster_size": 12, "k_min": 10, "cell_size": 12, "rule": "iterative"}
                           )["cluster_size"] == 12
    with pytest.raises(InvalidParameterError, match=r"k_min\+2=6"):
        params.validate("compare", {"cluster_size": 5, "rule": "iterative"})


def test_unknown_options_are_named():
    with pytest.raises(InvalidParameterError) as exc:
        params.validate("simplify", {"context": True})
    assert str(exc.value).startswith("simplify: unknown option(s) ['context']; accepted: [")
    with pytest.raises(InvalidParameterError, match=r"compare: unknown option\(s\) \['n_clusters'\]"):
        cloudsieve.compare("missing.laz", ratio=0.5, n_clusters=3)


def test_the_work_store_record_keeps_its_keys():
    """Work stores of earlier runs resume: the recorded options keep their names (halo_context as "context")."""
    record = params.run_record(params.validate("simplify", {"halo_context": True, "ratio": 0.5, "rule": "iterative"}))
    assert record == {"method": "km", "rule": "iterative", "threshold": 0.001, "ratio": 0.5, "count": None,
                      "cluster_size": 400, "cell_size": 200_000, "seed": 0, "context": True, "k0": 1.0, "k_min": 4}


# ----------------------------------------------------------------- the scheduler


def test_scheduler_check_passes_when_something_listens_and_names_the_address_when_not():
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        port = server.getsockname()[1]
        check_scheduler(f"tcp://127.0.0.1:{port}")
    with pytest.raises(SchedulerUnreachableError) as exc:
        check_scheduler(f"tcp://127.0.0.1:{port}", timeout=1.0)
    assert str(exc.value).startswith(f"cannot reach the dask scheduler at tcp://127.0.0.1:{port}: ")
    assert isinstance(exc.value, CloudsieveError) and isinstance(exc.value, ConnectionError)
    with pytest.raises(InvalidParameterError, match=r"scheduler address 'tcp://host' needs a host and a port"):
        check_scheduler("tcp://host")


def test_simplify_signature_defaults_are_the_options_defaults():
    """simplify()'s keyword defaults repeat params' (for its signature and help); they must not drift apart."""
    import inspect

    from cloudsieve.engine.simplify import simplify

    sig = inspect.signature(simplify).parameters
    for name, option in params.COMMANDS["simplify"].items():
        assert name in sig, name
        assert sig[name].default == option.default, (name, sig[name].default, option.default)
