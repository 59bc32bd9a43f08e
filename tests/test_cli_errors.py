"""The command line refuses bad input at once: exit 2, one exact message, nothing created.

Each case runs ``cloudsieve`` in this process (``main(argv)``) with its
output under an empty tmp folder, then checks the exit code, the whole of
stderr, and that the folder holds nothing new (no output, no
``*.cloudsieve.zarr`` work store: the refusal came before any work).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from cloudsieve.cli import main
from conftest import ROOT, shared_file

WRITABLE = "las (.las), laz (.laz), copc (.copc.laz), ply (.ply), xyz (.xyz .txt .csv .pts)"


def run(argv, capsys):
    """(exit code, stderr) of ``cloudsieve ARGV``."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().err


def listing(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


@pytest.fixture
def src():
    return shared_file("simple.laz")


def test_missing_source(tmp_path, capsys):
    missing, out = tmp_path / "missing.laz", tmp_path / "out.laz"
    rc, err = run(["simplify", missing, out, "--ratio", "0.5"], capsys)
    assert rc == 2
    assert err == f"cloudsieve simplify: error: {missing}: no such file\n"
    assert listing(tmp_path) == []


@pytest.mark.parametrize("name, message", [
    ("out.e57", "writing e57 files is not supported"),
    ("out.foo", "cannot write extension .foo (unknown format)"),
])
def test_destination_format_not_writable(tmp_path, capsys, src, name, message):
    out = tmp_path / name
    rc, err = run(["simplify", src, out, "--ratio", "0.5", "--scheduler", "sync"], capsys)
    assert rc == 2
    assert err == f"cloudsieve simplify: error: {out}: {message}; formats that can be written: {WRITABLE}\n"
    assert listing(tmp_path) == []


def test_destination_folder_is_a_file(tmp_path, capsys, src):
    afile = tmp_path / "afile"
    afile.write_bytes(b"")
    out, store = afile / "out.laz", tmp_path / "elsewhere.zarr"
    rc, err = run(["simplify", src, out, "--ratio", "0.5", "--store", store, "--scheduler", "sync"], capsys)
    assert rc == 2
    assert err == f"cloudsieve simplify: error: cannot write {out}: {afile} is not a folder\n"
    assert listing(tmp_path) == ["afile"]


def test_destination_folder_missing(tmp_path, capsys, src):
    out, store = tmp_path / "nowhere" / "out.laz", tmp_path / "elsewhere.zarr"
    rc, err = run(["simplify", src, out, "--ratio", "0.5", "--store", store, "--scheduler", "sync"], capsys)
    assert rc == 2
    assert err == f"cloudsieve simplify: error: cannot write {out}: folder {out.parent} does not exist\n"
    assert listing(tmp_path) == []


def test_scheduler_unreachable(tmp_path, capsys, src):
    out = tmp_path / "out.laz"
    rc, err = run(["simplify", src, out, "--ratio", "0.5", "--scheduler", "tcp://127.0.0.1:1"], capsys)
    assert rc == 2
    assert err == ("cloudsieve simplify: error: cannot reach the dask scheduler at tcp://127.0.0.1:1: "
                   "Connection refused (connect timeout 5 s)\n")
    assert listing(tmp_path) == []


@pytest.mark.parametrize("option, value, message", [
    ("--ratio", "0", "--ratio must be a number in (0, 1], got 0.0"),
    ("--ratio", "1.5", "--ratio must be a number in (0, 1], got 1.5"),
    ("--count", "0", "--count must be an integer >= 1, got 0"),
])
def test_target_out_of_range(tmp_path, capsys, src, option, value, message):
    out = tmp_path / "out.laz"
    rc, err = run(["simplify", src, out, option, value, "--scheduler", "sync"], capsys)
    assert rc == 2
    assert err == f"cloudsieve simplify: error: {message}\n"
    assert listing(tmp_path) == []


@pytest.mark.parametrize("option, value, message", [
    ("--ratio", "0", "--ratio must be a number in (0, 1], got 0.0"),
    ("--count", "0", "--count must be an integer >= 1, got 0"),
])
def test_compare_target_out_of_range(tmp_path, capsys, src, option, value, message):
    rc, err = run(["compare", src, option, value, "--report", tmp_path / "cmp", "--no-progress"], capsys)
    assert rc == 2
    assert err == f"cloudsieve compare: error: {message}\n"
    assert listing(tmp_path) == []


def test_pipeline_option_not_a_bool(tmp_path, capsys, src):
    out = tmp_path / "out" / "small.laz"
    doc = {"pipeline": [
        {"type": "readers.las", "filename": str(src)},
        {"type": "filters.entropy", "rule": "target", "ratio": 0.5, "halo_context": "yes"},
        {"type": "writers.las", "filename": str(out)},
    ]}
    path = tmp_path / "p.json"
    path.write_text(json.dumps(doc))
    rc, err = run(["run", path], capsys)
    assert rc == 2
    assert err == f"cloudsieve run: error: {path}: stage 2 (filters.entropy): halo_context must be true or false, got 'yes'\n"
    assert listing(tmp_path) == ["p.json"]


def test_missing_source_as_a_command_no_traceback(tmp_path):
    """The installed entry point: one line on stderr, exit 2 (it was a FileNotFoundError traceback, exit 1)."""
    missing = tmp_path / "missing.laz"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "cloudsieve", "simplify", str(missing), str(tmp_path / "out.laz"),
                           "--ratio", "0.5"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr == f"cloudsieve simplify: error: {missing}: no such file\n"
    assert listing(tmp_path) == []


def test_the_command_is_run_and_run_returns_mains_code(tmp_path):
    """``cloudsieve`` (the console script) and ``python -m cloudsieve`` both go through cli.run, which
    tunes the process and ends it without the modules' teardown: the same codes and messages as main()."""
    import tomllib

    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"cloudsieve": "cloudsieve.cli:run"}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    code = "import sys; from cloudsieve.cli import run; sys.argv[1:] = {!r}; sys.exit(run())"
    ok = subprocess.run([sys.executable, "-c", code.format(["--version"])], capture_output=True, text=True, env=env)
    assert (ok.returncode, ok.stdout.startswith("cloudsieve "), ok.stderr) == (0, True, "")
    missing = tmp_path / "missing.laz"
    bad = subprocess.run([sys.executable, "-c", code.format(["info", str(missing)])], capture_output=True, text=True,
                         env=env)
    assert (bad.returncode, bad.stderr) == (2, f"cloudsieve info: error: {missing}: no such file\n")


def test_the_command_ends_its_threads_and_runs_the_exit_handlers(tmp_path):
    """cli.run leaves by os._exit, but as the interpreter would: a thread still running is waited for, a
    thread pool never shut down is stopped (its worker waits for work: joined first, it never ends), then
    every exit handler runs, and stdout holds it all."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    code = ("import atexit, sys, threading, time; from concurrent.futures import ThreadPoolExecutor; "
            "from cloudsieve.cli import run; atexit.register(print, 'handler'); "
            "threading.Thread(target=lambda: (time.sleep(0.5), print('thread'))).start(); "
            "pool = ThreadPoolExecutor(1); pool.submit(print, 'pool'); "
            f"sys.argv[1:] = ['info', {str(shared_file('simple.las'))!r}]; sys.exit(run())")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path,
                          timeout=300)
    assert (proc.returncode, proc.stderr) == (0, "")
    assert "simple.las" in proc.stdout and "thread\n" in proc.stdout and "pool\n" in proc.stdout
    assert proc.stdout.endswith("handler\n")


def test_the_command_puts_numpys_arrays_on_small_pages_unless_told():
    """cli.run's engine.memory.small_pages_from_here: numpy, already imported, stops asking for huge pages, and so does every process
    started from it (the environment); NUMPY_MADVISE_HUGEPAGE set by the user is left as it is."""
    code = ("import os, subprocess, sys, numpy; from cloudsieve.engine.memory import small_pages_from_here; "
            "from numpy._core.multiarray import _set_madvise_hugepage as huge; small_pages_from_here(); was = huge(False); "
            "child = subprocess.run([sys.executable, '-c', 'from numpy._core.multiarray import "
            "_set_madvise_hugepage as h; print(h(False))'], capture_output=True, text=True).stdout.strip(); "
            "print(was, os.environ['NUMPY_MADVISE_HUGEPAGE'], child)")
    base = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    base["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])
    for preset, out in ((None, "False 0 False"), ("1", "True 1 True")):
        env = base if preset is None else {**base, "NUMPY_MADVISE_HUGEPAGE": preset}
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
        assert (proc.returncode, proc.stdout.strip(), proc.stderr) == (0, out, "")
