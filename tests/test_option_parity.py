"""One option spec, one check at every public entry: the same bad value, the same error.

Each of 12 bad values is fed to the four surfaces:

- the in-memory API :func:`cloudsieve.core.simplify_points`;
- the out-of-core API :func:`cloudsieve.simplify` on a real file;
- the command line ``python -m cloudsieve simplify SRC DST ...`` (a fresh
  interpreter): exit status 2, one line on stderr, no traceback, nothing
  created (no output, no work store);
- ``cloudsieve run --check p.json`` on a pipeline whose ``filters.entropy``
  stage holds the value (exit status 2, the same one line form).

The APIs raise :class:`InvalidParameterError` with the same message; the
command line prints that message with the option as its flag (``--ratio``,
``--cluster-size 1``); a pipeline names the stage, then the same message with
the option as its key (``ratio``, ``cluster_size``). ``workers`` is not an
option of the in-memory method (it runs on threads: ``threads``), so that
case checks that ``simplify_points`` has no such parameter and feeds the
three other surfaces.

A count above the cloud's points is not a bad value: every surface keeps all
the points and reports the count kept (params.py knows no cloud size).
:func:`test_params_is_a_leaf` checks what ``import cloudsieve.params`` loads.
"""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cloudsieve
from cloudsieve.core import simplify_points
from cloudsieve.errors import InvalidParameterError
from cloudsieve.params_spec import COMMANDS
from conftest import shared_file

SRC_DIR = str(Path(__file__).resolve().parents[1] / "src")
RULES = "iterative, threshold, target, coverage, eliminate"

# name: (options, API message, CLI flags, CLI message)
CASES = {
    "ratio 0": ({"ratio": 0}, "ratio must be a number in (0, 1], got 0.0",
                ["--ratio", "0"], "--ratio must be a number in (0, 1], got 0.0"),
    "ratio 1.5": ({"ratio": 1.5}, "ratio must be a number in (0, 1], got 1.5",
                  ["--ratio", "1.5"], "--ratio must be a number in (0, 1], got 1.5"),
    "ratio -0.1": ({"ratio": -0.1}, "ratio must be a number in (0, 1], got -0.1",
                   ["--ratio=-0.1"], "--ratio must be a number in (0, 1], got -0.1"),
    "count 0": ({"count": 0}, "count must be an integer >= 1, got 0",
                ["--count", "0"], "--count must be an integer >= 1, got 0"),
    "count -5": ({"count": -5}, "count must be an integer >= 1, got -5",
                 ["--count=-5"], "--count must be an integer >= 1, got -5"),
    "threshold -1": ({"threshold": -1}, "threshold must be a finite number >= 0, got -1.0",
                     ["--threshold=-1"], "--threshold must be a finite number >= 0, got -1.0"),
    "cluster_size 1": ({"ratio": 0.5, "cluster_size": 1},
                       "cluster_size=1 is too small: a cluster needs at least k_min+2=6 points",
                       ["--ratio", "0.5", "--cluster-size", "1"],
                       "--cluster-size 1 is too small: a cluster needs at least k_min+2=6 points"),
    "seed -1": ({"ratio": 0.5, "seed": -1}, "seed must be an integer >= 0, got -1",
                ["--ratio", "0.5", "--seed=-1"], "--seed must be an integer >= 0, got -1"),
    "unknown rule": ({"ratio": 0.5, "rule": "fastest"}, f"rule must be one of {RULES}, got 'fastest'",
                     ["--ratio", "0.5", "--rule", "fastest"], f"--rule must be one of {RULES}, got 'fastest'"),
    "unknown method": ({"ratio": 0.5, "method": "dbscan"}, "method must be one of fcm, km, got 'dbscan'",
                       ["--ratio", "0.5", "--method", "dbscan"], "--method must be one of fcm, km, got 'dbscan'"),
    "k_min 0": ({"ratio": 0.5, "k_min": 0}, "k_min must be an integer >= 1, got 0",
                ["--ratio", "0.5", "--k-min", "0"], "--k-min must be an integer >= 1, got 0"),
    "workers 0": ({"ratio": 0.5, "workers": 0}, "workers must be an integer >= 1, got 0",
                  ["--ratio", "0.5", "--workers", "0"], "--workers must be an integer >= 1, got 0"),
}
NOT_IN_MEMORY = {"workers"}  # simplify_points runs on threads (``threads``), not on dask workers


@pytest.fixture(scope="module")
def src() -> str:
    return str(shared_file("autzen_trim.laz"))


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": SRC_DIR + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-m", "cloudsieve", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=cwd)


@pytest.mark.parametrize("case", list(CASES))
def test_in_memory(case):
    options, message, _, _ = CASES[case]
    if set(options) & NOT_IN_MEMORY:
        assert not set(options) & NOT_IN_MEMORY & set(inspect.signature(simplify_points).parameters)
        return
    points = np.random.default_rng(0).random((500, 3))
    with pytest.raises(InvalidParameterError) as exc:
        simplify_points(points, **options)
    assert str(exc.value) == message


@pytest.mark.parametrize("case", list(CASES))
def test_out_of_core(case, src, tmp_path):
    options, message, _, _ = CASES[case]
    with pytest.raises(InvalidParameterError) as exc:
        cloudsieve.simplify(src, tmp_path / "out.laz", **options)
    assert str(exc.value) == message
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("case", list(CASES))
def test_command_line(case, src, tmp_path):
    _, _, flags, message = CASES[case]
    done = _cli("simplify", src, tmp_path / "out.laz", *flags, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr == f"cloudsieve simplify: error: {message}\n"
    assert "Traceback" not in done.stderr
    assert os.listdir(tmp_path) == []  # no output, no work store


@pytest.mark.parametrize("case", list(CASES))
def test_pipeline_check(case, src, tmp_path):
    options, message, _, _ = CASES[case]
    doc = {"pipeline": [
        {"type": "readers.las", "filename": src},
        {"type": "filters.entropy", **options},
        {"type": "writers.las", "filename": str(tmp_path / "out.laz")},
    ]}
    path = tmp_path / "p.json"
    path.write_text(json.dumps(doc))
    done = _cli("run", "--check", path, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr == f"cloudsieve run: error: {path}: stage 2 (filters.entropy): {message}\n"
    assert "Traceback" not in done.stderr
    assert sorted(os.listdir(tmp_path)) == ["p.json"]


def test_params_is_a_leaf():
    """params.py imports no cloudsieve.core module, no io, engine or scheduler, no numba or scipy."""
    probe = ("import sys, cloudsieve.params\n"
             "print(' '.join(sorted(m for m in sys.modules if m.startswith(('cloudsieve', 'numba', 'scipy')))))")
    env = {**os.environ, "PYTHONPATH": SRC_DIR + os.pathsep + os.environ.get("PYTHONPATH", "")}
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True,
                            env=env).stdout.split()
    assert sorted(loaded) == ["cloudsieve", "cloudsieve.address", "cloudsieve.errors", "cloudsieve.formats",
                              "cloudsieve.lazy", "cloudsieve.params", "cloudsieve.params_spec", "cloudsieve.params_values",
                              "cloudsieve.rule_table"]


def test_the_registry_refuses_a_rule_as_the_option_does():
    from cloudsieve.core import rules

    with pytest.raises(InvalidParameterError) as exc:
        rules.get("fastest")
    assert str(exc.value) == CASES["unknown rule"][1]
    assert tuple(rules.RULES) == rules.names() and all(rules.get(name).name == name for name in rules.names())


#: option names still defined more than once across the commands: each with what differs (the work left)
SEVERAL = {
    "rule": "compare takes a list; the in-memory API defaults to iterative, the commands resolve it",
    "threshold": "the in-memory API's default is the paper's S, the commands' is resolved with the rule",
    "format": "ingest's names a readable format, simplify's and export's a writable one",
}


def test_each_option_name_is_defined_once():
    definitions: dict[str, set[int]] = {}
    for spec in COMMANDS.values():
        for name, option in spec.items():
            definitions.setdefault(name, set()).add(id(option))
    assert sorted(n for n, d in definitions.items() if len(d) > 1) == sorted(SEVERAL)


def test_each_command_has_one_frozen_options_object_from_the_spec():
    """params.options: the command's validated values (normalised), as a frozen object with one field per option
    of params_spec, in its order; it pickles (a task may carry it)."""
    import dataclasses
    import pickle

    from cloudsieve.params import OPTION_CLASSES, options

    assert set(OPTION_CLASSES) == set(COMMANDS)
    for command, cls in OPTION_CLASSES.items():
        assert [f.name for f in dataclasses.fields(cls)] == list(COMMANDS[command])
    o = options("evaluate", {"sample": 1e3, "report_dir": Path("r")})
    assert type(o).__name__ == "EvaluateOptions" and (o.sample, o.report_dir, o.tiles) == (1000, "r", None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.sample = 5
    assert pickle.loads(pickle.dumps(o)) == o
    probe = "import pickle, sys; print(pickle.loads(sys.stdin.buffer.read()).sample)"  # a process without the class
    env = {**os.environ, "PYTHONPATH": SRC_DIR + os.pathsep + os.environ.get("PYTHONPATH", "")}
    assert subprocess.run([sys.executable, "-c", probe], input=pickle.dumps(o), capture_output=True, check=True,
                          env=env).stdout == b"1000\n"
    with pytest.raises(InvalidParameterError) as exc:
        options("compare", {"count": 0})
    assert str(exc.value) == "count must be an integer >= 1, got 0"


def test_the_tile_grid_refuses_no_tile_size_in_the_options_words():
    from cloudsieve.store.tiles import check_grid

    with pytest.raises(InvalidParameterError) as exc:
        check_grid(np.zeros((2, 3)), None, "x")
    assert str(exc.value) == "tile_size must be a finite number > 0, got None"
