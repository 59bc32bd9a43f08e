"""The one task runner: dask batches in argument order, streamed calls, forked children."""

from __future__ import annotations

import importlib
import logging
import os

import numpy as np
import pytest

from cloudsieve.core.rules import DEFAULT_RULE, THRESHOLD_RULE
from cloudsieve.engine import pool as pool_module
from cloudsieve.engine.calls import forked, imap
from cloudsieve.engine.runner import PeakMemory, Runner
from cloudsieve import progress
from cloudsieve.progress import stage_bar
from cloudsieve.errors import CloudsieveError, InvalidParameterError
from cloudsieve.rule_table import TARGETS, targets_of


@pytest.mark.parametrize("scheduler, workers", [("sync", None), ("threads", 2), ("processes", 2)])
def test_results_come_in_argument_order(scheduler, workers):
    seen = []

    class Bars:
        def __call__(self, stage, total, unit):
            import contextlib

            seen.append((stage, total, unit))
            return contextlib.nullcontext(lambda n: seen.append(n))

    run = Runner(scheduler, workers, bars=Bars())
    try:
        out = run(divmod, [(i, 7) for i in range(40)], "stage: test")
        assert out == [divmod(i, 7) for i in range(40)]
        assert run(divmod, [], "empty") == []
    finally:
        run.close()
    assert seen[0] == ("stage: test", 40, "task") and seen[1:] == [1] * 40


def _mark(i, folder, deps, wait):
    """Write folder/i after *wait* seconds; True if the files of *deps* were all there when it started."""
    import time
    from pathlib import Path

    ready = all((Path(folder) / str(j)).exists() for j in deps)
    time.sleep(wait)
    (Path(folder) / str(i)).write_text("done")
    return ready


@pytest.mark.parametrize("scheduler, workers, limit", [("sync", None, None), ("threads", 2, None),
                                                        ("processes", 2, None), (None, 2, "1GB")])
def test_a_task_starts_after_the_tasks_it_waits_for(tmp_path, scheduler, workers, limit):
    """``after=``: the colours of the eliminate rule (a cell reads the results of lower-colour neighbours)."""
    after = [[], [], [0], [0, 1], [], [2, 4]]
    args = [(i, str(tmp_path), after[i], 0.5 if i == 0 else 0.0) for i in range(len(after))]
    run = Runner(scheduler, workers, memory_limit=limit)
    try:
        assert run(_mark, args, "stage: test", after=after) == [True] * len(after)
        with pytest.raises(InvalidParameterError, match="after must list, for each task, indices of earlier tasks"):
            run(_mark, args[:2], "stage: test", after=[[1], []])
    finally:
        run.close()


def test_unknown_scheduler_and_memory_limit_without_processes_are_refused():
    with pytest.raises(InvalidParameterError, match="unknown scheduler 'fast'"):
        Runner("fast")
    with pytest.raises(InvalidParameterError, match=r"memory_limit \(1GB\) needs worker processes"):
        Runner("threads", memory_limit="1GB")


def test_task_threads_share_the_cores():
    cores = os.cpu_count() or 1
    assert Runner("sync").task_threads == cores
    assert Runner("threads", 1).task_threads == cores
    assert Runner("threads", cores).task_threads == 1


def test_every_preloaded_module_imports():
    """The fork server imports these once; a stale name would only show as slower workers."""
    for name in pool_module.preload(TARGETS):
        importlib.import_module(name)


def test_the_default_rule_s_fork_server_imports_no_scoring_path():
    """scipy's tree and the scoring kernels (0.25-0.3 s of the fork server's start) only for the runs that score."""
    assert not {"scipy.spatial", "cloudsieve.core.kernels.knn"} & set(pool_module.preload(targets_of(DEFAULT_RULE)))
    assert "scipy.spatial" in pool_module.preload(targets_of(THRESHOLD_RULE))
    assert pool_module.preload(TARGETS)[-1] == "cloudsieve.engine.forkserver_init"  # last: it warms up


def test_imap_in_process_streams_in_order_with_shared_arguments():
    best = np.full(3, np.inf)
    items = (((np.full(3, float(v)),), {"scale": 2.0}) for v in (5, 3, 4))

    def smaller(x, shared, scale):
        return np.minimum(x * scale, shared)

    out = []
    for d in imap(smaller, items, None, shared=(best,)):
        np.minimum(best, d, out=best)  # the consumer may update a shared array between calls
        out.append(float(d[0]))
    assert out == [10.0, 6.0, 6.0]
    assert list(imap(divmod, [((9,), {}), ((8,), {})], shared=(4,))) == [(2, 1), (2, 0)]


def test_stage_bar_counts_into_the_bars_and_without_bars_does_nothing(caplog, capfd):
    """With the CLI's bars (stderr not a terminal here: one log line when the stage ends) the updates are
    counted; without bars the update takes a count and nothing is shown or logged."""
    with caplog.at_level(logging.INFO, logger="cloudsieve.progress"):
        with stage_bar(progress.bar, "cells", 3, "task") as update:
            update(2)
            update(1)
        assert [r.getMessage().split(" in ")[0] for r in caplog.records] == ["cells: 3 tasks"]
        caplog.clear()
        with stage_bar(None, "ingest", None, "pt") as update:
            assert update(5) is None
        assert caplog.records == []
    assert capfd.readouterr() == ("", "")


def test_peak_memory_samples_this_process():
    import psutil

    # this process alone: the children counted by PeakMemory (workers of earlier tests) may exit meanwhile
    base = psutil.Process().memory_info().rss
    with PeakMemory(interval=0.01) as peak:
        a = np.ones(40_000_000, dtype=np.uint8)  # touched: resident
    assert peak.peak >= base + 30_000_000
    del a


def test_process_tree_rss_from_proc_is_psutils_sum():
    """/proc read directly (cloudsieve.engine.memory: psutil's import is slow) against psutil's sum over this
    process and its children, a child holding 80 MiB it has touched; the two read a moment apart."""
    import subprocess
    import sys

    import psutil

    from cloudsieve.engine.memory import _proc_tree_rss

    code = "import sys, time; x = bytearray(80 << 20); x[::4096] = bytes(len(x[::4096])); print(1, flush=True); " \
           "sys.stdin.read()"
    child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline() == b"1\n"  # its 80 MiB resident
        proc = psutil.Process()
        tree = [proc, *proc.children(recursive=True)]
        assert child.pid in [p.pid for p in tree]
        expected = sum(p.memory_info().rss for p in tree)
        got = _proc_tree_rss()
        assert abs(got - expected) < 8 << 20 and got > (80 << 20)
    finally:
        child.communicate(b"")


def test_peak_memory_counts_a_child_started_after_it_began():
    """PeakMemory searches /proc for children every TREE_EVERY samples and reads only their statm in between:
    a child started while it samples, holding 80 MiB it has touched, is in its peak."""
    import subprocess
    import sys
    import time

    from cloudsieve.engine.memory import TREE_EVERY, PeakMemory, process_tree_rss

    code = "import sys; x = bytearray(80 << 20); x[::4096] = bytes(len(x[::4096])); print(1, flush=True); " \
           "sys.stdin.read()"
    with PeakMemory(interval=0.01) as peak:
        base = process_tree_rss()
        child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        try:
            assert child.stdout.readline() == b"1\n"
            time.sleep(3 * TREE_EVERY * 0.01 + 0.2)  # a search of /proc and samples after it
        finally:
            child.communicate(b"")
    assert peak.peak >= base + (70 << 20)


def test_small_pages_turns_numpys_huge_pages_off_inside_and_obeys_the_variable(monkeypatch):
    """engine.memory.small_pages: numpy's huge-page advice off inside, as it was after (on or off); with
    NUMPY_MADVISE_HUGEPAGE set, numpy's switch is left alone."""
    from cloudsieve.engine.memory import HUGEPAGE_ENV, set_huge_pages, small_pages

    monkeypatch.delenv(HUGEPAGE_ENV, raising=False)
    before = set_huge_pages(True)
    try:
        for outside in (True, False):
            set_huge_pages(outside)
            with small_pages():
                assert set_huge_pages(False) is False
            assert set_huge_pages(outside) is outside
        monkeypatch.setenv(HUGEPAGE_ENV, "1")
        set_huge_pages(True)
        with small_pages():
            assert set_huge_pages(True) is True
    finally:
        set_huge_pages(before)


def _fail():
    raise ZeroDivisionError("boom")


def _die():
    os._exit(3)


def test_forked_children_start_from_the_parent_state():
    """Every child starts from the parent's random state: the same call gives the same value each time."""
    state = np.random.get_state()
    values = forked([(np.random.random,)] * 4, max_parallel=2)
    assert len(set(values)) == 1
    assert values[0] == np.random.random()  # the parent's state was not advanced by the children
    np.random.set_state(state)


def test_forked_results_in_order_and_errors_named():
    assert forked([(divmod, i, 3) for i in range(7)], max_parallel=3) == [divmod(i, 3) for i in range(7)]
    with pytest.raises(CloudsieveError, match="pymeshlab failed: ZeroDivisionError: boom"):
        forked([(divmod, 1, 1), (_fail,)])
    with pytest.raises(CloudsieveError, match=r"metro crashed in its worker process \(exit code 3\)"):
        forked([(_die,)], name="metro")


def _pid(_):
    return os.getpid()


def test_prestart_starts_the_workers_in_the_background_and_close_ends_them():
    """The local pool's workers start before the first task (from the fork server, which this thread starts:
    it dies with the thread that started it); the tasks run as before; close() leaves no worker alive."""
    r = Runner("processes", 2)
    try:
        r.prestart()
        r.prestart()  # once
        r._prestart.join()
        workers = dict(r._pool._processes)
        assert len(workers) == 2 and all(p.is_alive() for p in workers.values())
        assert set(r(_pid, [(i,) for i in range(4)], "test")) <= set(workers) | {os.getpid()}
    finally:
        r.close()
    assert not any(p.is_alive() for p in workers.values())


def test_prestart_is_a_no_op_without_a_local_pool():
    r = Runner("threads", 2)
    try:
        r.prestart()
        assert getattr(r, "_prestart", None) is None
        assert r(_pid, [(0,)], "test") == [os.getpid()]
    finally:
        r.close()


BOOT = """
import sys
from multiprocessing import forkserver
from cloudsieve.engine.runner import boot
scheduler, limit = sys.argv[1] or None, sys.argv[2] or None
if __name__ == "__main__":
    boot(scheduler, limit, ("common",))
    print(forkserver._forkserver._forkserver_pid is not None)
"""


@pytest.mark.parametrize("scheduler, limit, started", [("", "", True), ("processes", "", True),
                                                       ("sync", "", False), ("threads", "", False),
                                                       ("processes", "1GB", False),
                                                       ("tcp://127.0.0.1:1", "", False)])
def test_boot_starts_the_fork_server_only_for_the_local_pool(tmp_path, scheduler, limit, started):
    """boot() starts now the fork server a Runner of the same options would start (the default and "processes"
    without a memory limit), and nothing for the other schedulers; in a fresh process, where none runs yet."""
    import subprocess
    import sys

    script = tmp_path / "boot.py"
    script.write_text(BOOT)
    out = subprocess.run([sys.executable, str(script), scheduler, limit], capture_output=True, text=True,
                         timeout=120, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(started)


def _checksum(a, b, scale):
    return float(a.sum() + b.sum()) * scale


def test_a_large_array_argument_is_scattered_not_sent_in_the_graph():
    """On a dask.distributed cluster an array argument above SCATTER_BYTES (the partition's sample: up to 24 MB)
    goes to the workers ahead of its task: the same results, and no "Sending large graph" warning from dask."""
    import warnings

    from distributed import Client, LocalCluster

    from cloudsieve.engine.runner import NO_HTTP_PORT, SCATTER_BYTES

    big = np.arange(3 * (SCATTER_BYTES // 8 + 1), dtype=np.float64).reshape(-1, 3)  # 24 MB
    big = np.repeat(big, 8, axis=0)
    small = np.ones(10)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster, Client(cluster) as client:
        run = Runner(client=client)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out = run(_checksum, [(big, small, 1.0), (big, small, 2.0)], "test")
    assert big.nbytes > 10 * 2**20
    assert out == [float(big.sum() + 10) * s for s in (1.0, 2.0)]
    assert not [w for w in caught if "large graph" in str(w.message)]
