"""A run killed in its 4th elimination task, then resumed: the steps the kill-and-resume tests share."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import zarr

from cloudsieve.engine.pause import PAUSE_ENV


def kill_at(args: list[str], pause: str, marker: Path, env: dict) -> subprocess.Popen:
    """Run ``cloudsieve *args*`` with the test hook *pause* (``task:STAGE#K``, :mod:`cloudsieve.engine.pause`) and
    SIGKILL it once it pauses there (*marker* written); returns the killed process."""
    proc = subprocess.Popen([sys.executable, "-m", "cloudsieve", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, env=dict(env, **{PAUSE_ENV: f"{pause}={marker}"}))
    deadline = time.monotonic() + 600  # a guard against a hang only: the run stops there whatever its speed
    try:
        while proc.poll() is None and time.monotonic() < deadline and not marker.exists():
            time.sleep(0.05)
        assert marker.exists(), f"the run did not reach its pause ({proc.returncode})"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(60)
    finally:
        if proc.poll() is None:  # pragma: no cover
            proc.kill()
    return proc


def kill_then_resume(args: list[str], store: Path, marker: Path) -> dict:
    """Run ``cloudsieve *args`` (one thread, 6 cells), kill it when its 4th ``cells: apply`` task pauses
    (*marker* written), check that 3 cells of *store* are done, then resume it; returns the resumed run's
    ``--json`` summary."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    kill_at(args, "task:cells: apply#4", marker, env)
    done = np.asarray(zarr.open_group(str(store), mode="r")["simplify/done"][:]).astype(bool)
    assert int(done.sum()) == 3 < len(done) == 6
    rc = subprocess.run([sys.executable, "-m", "cloudsieve", *args, "--resume", "--json"], capture_output=True,
                        env=env)
    assert rc.returncode == 0, rc.stderr.decode()
    return json.loads(rc.stdout.decode())
