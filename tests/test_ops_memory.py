"""A distributed run reports its workers' peak memory, not the client's.

A real LocalCluster of two worker processes on loopback, reached through a
given client (API) and through ``--scheduler tcp://...`` (CLI): each worker
reports its own resident memory (``client.run``); the summary gives the peak
of their sum, labelled with the number of workers.
"""

from __future__ import annotations

import json
import resource
import threading

import pytest

from cloudsieve import simplify
from cloudsieve.cli import main
from cloudsieve.engine.memory import LOCAL_SCOPE, PeakMemory, worker_rss
from conftest import shared_file
from cloudsieve.engine.runner import NO_HTTP_PORT

LABEL = "2 dask workers (sum of their resident memory)"


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as c:
        with Client(c) as client:
            yield c, client


def lifetime_peaks(client) -> int:
    """The sum of the workers' own lifetime peak RSS (ru_maxrss, kB on Linux), in bytes."""
    return sum(client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024).values())


def test_a_distributed_run_reports_the_workers_peak(cluster, tmp_path):
    _, client = cluster
    s = simplify(shared_file("bun_zipper.ply"), tmp_path / "o.ply", ratio=0.5, client=client, cell_size=10_000)
    now = client.run(worker_rss)
    assert len(now) == 2
    assert s.peak_memory_of == LABEL
    # a sum of simultaneous samples of the workers: at most the sum of their own peaks, and above any one of them
    assert min(now.values()) < s.peak_memory <= lifetime_peaks(client)
    assert f"MiB  ({LABEL})" in str(s)


def test_the_cli_on_a_scheduler_address_reports_the_workers(cluster, tmp_path, capsys):
    c, client = cluster
    capsys.readouterr()
    rc = main(["simplify", str(shared_file("simple.las")), str(tmp_path / "o.las"), "--rule", "iterative",
               "--scheduler", c.scheduler_address, "--json", "--no-progress"])
    out = capsys.readouterr().out
    assert rc == 0
    record = json.loads(out)
    assert record["peak_memory_of"] == LABEL
    assert 0 < record["peak_memory"] <= lifetime_peaks(client)


def _high_water(pid: int) -> int:
    """A process's own lifetime peak of resident memory (VmHWM, bytes; 0 when it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmHWM:"))
    except FileNotFoundError:
        return 0


def test_a_local_run_reports_this_process_and_its_children(tmp_path):
    """The peak holds this process's resident memory (at least 90% of it before the run: in bytes, not kB) and
    no more than the lifetime peaks of this process and its children (the cluster's workers among them)."""
    import psutil

    before = psutil.Process().memory_info().rss
    s = simplify(shared_file("simple.las"), tmp_path / "o.las", rule="iterative", scheduler="sync")
    tree = [psutil.Process(), *psutil.Process().children(recursive=True)]
    assert s.peak_memory_of == LOCAL_SCOPE
    assert 0.9 * before <= s.peak_memory <= sum(_high_water(p.pid) for p in tree)


def test_sampling_the_workers_stops_before_their_client_closes(cluster):
    """A ``client.run`` in flight when its client closes never returns: stop() ends the sampling first.

    Sampling without a pause, closing the client straight after stop(): the
    order the run uses. The other order hung within five rounds.
    """
    from distributed import Client

    c, _ = cluster
    for _ in range(8):
        client = Client(c.scheduler_address)
        with PeakMemory(worker_interval=0.0) as peak:
            peak.watch_workers(client)
            peak.stop()
            assert "cloudsieve-peak-memory" not in {t.name for t in threading.enumerate()}
            client.close()
        assert peak.peak > 0 and peak.workers == 2


def test_a_run_exporting_in_the_driver_counts_the_workers_cpu(cluster, tmp_path):
    """PLY out: the client closes before the driver's export; the workers' CPU is taken before it closes."""
    c, _ = cluster
    s = simplify(shared_file("simple.las"), tmp_path / "o.ply", rule="iterative", scheduler=c.scheduler_address)
    assert s.cpu_seconds["workers"] > 0
    assert s.peak_memory_of == LABEL
