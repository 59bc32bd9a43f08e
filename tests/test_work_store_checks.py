"""Issue 27, item 7: a named work store is kept after success, and checked before any scheduler is contacted.

``--store PATH`` is kept after a successful run (``--help`` says so); a store
made from another source or with other options is refused before the
scheduler is contacted: with an unreachable scheduler address the error is the
store's, not the scheduler's, and nothing else happens.
"""

from __future__ import annotations

import json

import numpy as np

from cloudsieve.cli import main
from cloudsieve.store import is_store
from conftest import shared_file
from test_cli_help import COMMANDS


def run(argv, capsys):
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def test_the_help_says_a_named_store_is_kept():
    text = COMMANDS["simplify"]._option_string_actions["--store"].help
    assert text.startswith("work store (path or fsspec URL), kept after success")
    assert "DST.cloudsieve.zarr, removed on success" in text


def test_a_named_store_is_kept_after_success(tmp_path, capsys):
    store = tmp_path / "work.zarr"
    rc, out, _ = run(["simplify", shared_file("simple.las"), tmp_path / "o.las", "--ratio", "0.5", "--store", store,
                      "--scheduler", "sync", "--no-progress", "--json"], capsys)
    assert rc == 0 and is_store(str(store)) and json.loads(out)["store"] == str(store)
    rc, out, _ = run(["simplify", shared_file("simple.las"), tmp_path / "d.las", "--ratio", "0.5", "--scheduler",
                      "sync", "--no-progress", "--json"], capsys)
    assert rc == 0 and json.loads(out)["store"] is None and not (tmp_path / "d.las.cloudsieve.zarr").exists()


def test_a_store_with_other_options_is_refused_before_the_scheduler(tmp_path, capsys):
    src, store = shared_file("simple.las"), tmp_path / "work.zarr"
    base = ["simplify", src, "--store", store, "--no-progress"]
    assert run([*base, tmp_path / "o.las", "--ratio", "0.5", "--scheduler", "sync"], capsys)[0] == 0
    # nothing answers at port 1: the scheduler's check would say so, but the store is checked first
    rc, _, err = run([*base, tmp_path / "p.las", "--ratio", "0.25", "--scheduler", "tcp://127.0.0.1:1"], capsys)
    assert rc == 2
    assert err == (f"cloudsieve simplify: error: store {store} holds a run with other parameters ratio: stored 0.5, "
                   "asked 0.25; pass --overwrite to discard it\n")


def test_a_store_of_another_source_is_refused_before_the_scheduler(tmp_path, capsys):
    store = tmp_path / "work.zarr"
    other = tmp_path / "other.xyz"
    np.savetxt(other, np.random.default_rng(0).random((50, 3)), fmt="%.6f")
    assert run(["simplify", shared_file("simple.las"), tmp_path / "o.las", "--ratio", "0.5", "--store", store,
                "--scheduler", "sync", "--no-progress"], capsys)[0] == 0
    rc, _, err = run(["simplify", other, tmp_path / "p.las", "--ratio", "0.5", "--store", store, "--scheduler",
                      "tcp://127.0.0.1:1", "--no-progress"], capsys)
    assert rc == 2
    assert err.startswith(f"cloudsieve simplify: error: work store {store} was ingested from ")
    assert err.endswith("; pass --overwrite to start again\n")
