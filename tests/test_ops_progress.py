"""Issue 13, item 7: progress with and without a terminal.

Without a terminal (stderr piped), every command prints one log line per
stage with its count and seconds, not bars; in a terminal, evaluate's surface
stage has a bar (with elapsed time) and the global threshold's histogram
rounds are one bar, not one per round. The commands run as a user runs them:
``python -m cloudsieve`` in a subprocess, stderr piped (or a pseudo-terminal).
"""

from __future__ import annotations

import fcntl
import json
import os
import pty
import re
import struct
import subprocess
import sys
import termios
import threading
from contextlib import contextmanager

from cloudsieve import evaluate, simplify
from conftest import ROOT, shared_file

LINE = r"INFO cloudsieve\.progress: {stage}: [\d,]+ {unit} in \d+\.\d s"


def cloudsieve(argv, cwd, stderr=subprocess.PIPE):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "cloudsieve", *map(str, argv)], stdout=subprocess.PIPE,
                          stderr=stderr, text=True, env=env, cwd=cwd)


def stage_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("INFO cloudsieve.progress: ")]


def assert_stages(stderr: str, stages: list[tuple[str, str]]) -> None:
    """Exactly one line per stage, in this order, and no other progress line; no bar drawn."""
    lines = stage_lines(stderr)
    assert len(lines) == len(stages), lines
    for line, (stage, unit) in zip(lines, stages):
        assert re.fullmatch(LINE.format(stage=re.escape(stage), unit=unit), line), line
    assert "\r" not in stderr and "it/s" not in stderr


# a LAS source is ingested by tasks, and the partition reads its sample from the store ("partition: sample")
SIMPLIFY_STAGES = [("ingest", "points"), ("partition: sample", "tasks?"), ("partition: fit", "tasks?"),
                   ("partition: label", "tasks?"),
                   ("cells: score", "tasks?"), ("cells: threshold", "tasks?"), ("cells: apply", "tasks?"),
                   ("merge", "tasks?"), ("export", "points")]


def test_simplify_without_a_terminal_logs_one_line_per_stage(tmp_path):
    proc = cloudsieve(["simplify", "--rule", "iterative", shared_file("simple.las"), tmp_path / "o.las", "--ratio",
                       "0.5", "--scheduler",
                       "sync"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_stages(proc.stderr, SIMPLIFY_STAGES)
    proc = cloudsieve(["simplify", "--rule", "iterative", shared_file("simple.las"), tmp_path / "p.las", "--scheduler",
                       "sync"], tmp_path)
    assert_stages(proc.stderr, [s for s in SIMPLIFY_STAGES if s[0] not in ("cells: score", "cells: threshold",
                                                                          "cells: apply")][:4]
                  + [("cells", "tasks?"), ("merge", "tasks?"), ("export", "points")])
    proc = cloudsieve(["simplify", "--rule", "iterative", shared_file("simple.las"), tmp_path / "q.las",
                       "--no-progress", "--scheduler", "sync"], tmp_path)
    assert stage_lines(proc.stderr) == []


def test_ingest_evaluate_compare_without_a_terminal(tmp_path):
    src = shared_file("simple.las")
    proc = cloudsieve(["ingest", src, tmp_path / "s.zarr"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_stages(proc.stderr, [(f"ingest {src}", "points")])
    assert cloudsieve(["simplify", "--rule", "iterative", src, tmp_path / "o.las", "--scheduler", "sync",
                       "--no-progress"],
                      tmp_path).returncode == 0
    proc = cloudsieve(["evaluate", src, tmp_path / "o.las", "--tiles", "1"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_stages(proc.stderr, [("point errors", "points"), ("surface", "tiles?")])
    proc = cloudsieve(["compare", "--rule", "iterative", src, "--ratio", "0.5", "--methods", "km,random",
                       "--no-surface"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_stages(proc.stderr, [("methods", "methods")])


def test_run_and_demo_without_a_terminal(tmp_path):
    src = tmp_path / "in.las"
    src.write_bytes(shared_file("simple.las").read_bytes())
    pipeline = tmp_path / "p.json"
    pipeline.write_text(json.dumps({"pipeline": [
        {"type": "readers.las", "filename": str(src)},
        {"type": "filters.entropy", "rule": "iterative", "ratio": 0.5, "scheduler": "sync"},
        {"type": "writers.las", "filename": str(tmp_path / "{stem}-out.las")},
        {"type": "evaluate", "tiles": 1}]}))
    proc = cloudsieve(["run", pipeline], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_stages(proc.stderr, SIMPLIFY_STAGES + [("point errors", "points"), ("surface", "tiles?"),
                                                  ("pipeline", "points")])
    proc = cloudsieve(["demo", "--rule", "iterative", "--points", "5000", "--out", tmp_path / "demo", "--scheduler",
                       "sync"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_stages(proc.stderr, SIMPLIFY_STAGES + [("point errors", "points"), ("surface", "tiles?")])


@contextmanager
def terminal():
    """A pseudo-terminal of 100 columns: (the fd to give as stderr, a function returning what was drawn).

    Read in a thread as it is drawn, so the command never waits on a full buffer.
    """
    main_fd, sub_fd = pty.openpty()
    fcntl.ioctl(sub_fd, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    chunks = []

    def drain() -> None:
        while True:
            try:
                data = os.read(main_fd, 65536)
            except OSError:  # the other side closed
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()

    def read() -> str:
        os.close(sub_fd)
        reader.join(timeout=30)
        return b"".join(chunks).decode(errors="replace")

    try:
        yield sub_fd, read
    finally:
        os.close(main_fd)


def test_in_a_terminal_evaluate_draws_a_surface_bar(tmp_path):
    src = shared_file("simple.las")
    assert cloudsieve(["simplify", "--rule", "iterative", src, tmp_path / "o.las", "--scheduler", "sync",
                       "--no-progress"],
                      tmp_path).returncode == 0
    with terminal() as (fd, read):
        proc = cloudsieve(["evaluate", src, tmp_path / "o.las", "--tiles", "1"], tmp_path, stderr=fd)
        drawn = read()
    assert proc.returncode == 0, drawn
    assert "point errors:" in drawn and "surface:" in drawn
    assert "INFO cloudsieve.progress" not in drawn  # bars, not lines


class Recorder:
    """``bars(stage, total, unit)`` that records each stage opened and its updates (what the CLI would draw)."""

    def __init__(self):
        self.opened = []

    @contextmanager
    def __call__(self, stage, total, unit):
        rec = {"stage": stage, "total": total, "unit": unit, "done": 0}
        self.opened.append(rec)

        def update(n):
            rec["done"] += n

        yield update


def test_the_threshold_search_is_one_bar(tmp_path):
    """cells: threshold runs several histogram rounds: one bar counts them all."""
    bars = Recorder()
    simplify(shared_file("bun_zipper.ply"), tmp_path / "o.ply", rule="iterative", ratio=0.5, scheduler="sync",
             cell_size=10_000,
             bars=bars)
    opened = [r["stage"] for r in bars.opened]
    assert opened.count("cells: threshold") == 1
    rec = next(r for r in bars.opened if r["stage"] == "cells: threshold")
    assert rec["done"] >= 2 * 4  # at least one histogram round and the gather, over 4 cells


def test_evaluate_gives_the_surface_stage_a_bar(tmp_path):
    bars = Recorder()
    src = shared_file("simple.las")
    simplify(src, tmp_path / "o.las", rule="iterative", scheduler="sync")
    evaluate(src, tmp_path / "o.las", tiles=1, bars=bars)
    assert [(r["stage"], r["unit"], r["done"]) for r in bars.opened] == [("point errors", "pt", 1065),
                                                                         ("surface", "tile", 1)]
