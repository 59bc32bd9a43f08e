"""``simplify --exact``: a ratio or count that cannot be met is an error.

Without ``--exact`` it is a warning (tests/test_ops_inputs.py); with it, the
same text is the error, the exit code is 2 and nothing is written (neither
DST nor the default work store). Each option name has one meaning: ``exact``
is simplify's (off by default), ``strict`` evaluate's (refuse clouds of other
CRS or units; on by default, ``--no-strict`` / ``--force`` turn it off);
``simplify`` knows no ``--strict``.
"""

from __future__ import annotations

import numpy as np
import pytest

from cloudsieve import simplify
from cloudsieve.cli import main
from cloudsieve.errors import TargetNotMetError
from cloudsieve.params import COMMANDS
from conftest import shared_file


def run(argv, capsys):
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def test_exact_count_beyond_the_input_is_an_error(tmp_path, capsys):
    src = shared_file("simple.las")
    rc, out, err = run(["simplify", src, tmp_path / "o.las", "--rule", "target", "--count", "5000", "--exact",
                        "--scheduler", "sync", "--no-progress"], capsys)
    assert rc == 2 and out == ""
    assert err == (f"cloudsieve simplify: error: {src}: asked to keep 5,000 points, kept 1,065: the input holds "
                   "only 1,065 points\n")
    assert list(tmp_path.iterdir()) == []  # no output, no work store


def test_exact_identical_points(tmp_path, capsys):
    """1,000 identical points with --ratio 0.5: one distinct point, kept once."""
    src = tmp_path / "same.xyz"
    np.savetxt(src, np.tile([[1.0, 2.0, 3.0]], (1000, 1)), fmt="%.3f")
    rc, _, err = run(["simplify", src, tmp_path / "o.las", "--rule", "iterative", "--ratio", "0.5", "--exact",
                      "--scheduler", "sync", "--no-progress"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve simplify: error: {src}: asked to keep 500 points, kept 1: 999 of the 1,000 points "
                   "are exact duplicates, kept once (keep_duplicates keeps them)\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["same.xyz"]


def test_exact_with_a_met_count_succeeds_and_the_api_raises(tmp_path):
    src = shared_file("simple.las")
    s = simplify(src, tmp_path / "o.las", rule="target", count=500, scheduler="sync", exact=True)
    assert s.kept == 500
    with pytest.raises(TargetNotMetError, match=r"asked to keep 2,000 points, kept 1,065"):
        simplify(src, tmp_path / "p.las", rule="target", count=2000, scheduler="sync", exact=True)
    assert not (tmp_path / "p.las").exists()


def test_exact_names_resolved(capsys):
    assert COMMANDS["simplify"]["exact"].default is False and COMMANDS["simplify"]["exact"].flag == "--exact"
    assert "strict" not in COMMANDS["simplify"] and "exact" not in COMMANDS["evaluate"]
    with pytest.raises(SystemExit) as exc:
        main(["simplify", "a.las", "b.las", "--ratio", "0.5", "--strict"])
    assert exc.value.code == 2 and "unrecognized arguments: --strict" in capsys.readouterr().err
    assert COMMANDS["evaluate"]["strict"].default is True and COMMANDS["evaluate"]["strict"].flag == "--no-strict"
    assert COMMANDS["evaluate"]["strict"].aliases == ("--force",)
