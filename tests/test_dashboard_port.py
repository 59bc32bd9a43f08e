"""Issue 48, item 11: no LocalCluster of the tests or of cloudsieve serves HTTP on dask's default port 8787.

A scheduler serves HTTP (its dashboard, or health checks alone) on port 8787
unless told otherwise, and warns "Port 8787 is already in use" when anything
else holds it. Every LocalCluster passes ``scheduler_kwargs=NO_HTTP_PORT``
(any free port); pytest turns that warning into an error (pyproject's
``filterwarnings``), so a cluster that would warn fails its test.
"""

from __future__ import annotations

import ast
import socket
import warnings

import pytest

from conftest import ROOT


def _local_clusters(path) -> list[tuple[int, ast.Call]]:
    """The calls in *path* that start a LocalCluster: ``LocalCluster(...)``, and ``Client()`` with no address."""
    tree = ast.parse(path.read_text(), filename=str(path))
    calls = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
            own = name == "Client" and not node.args and not any(k.arg == "address" for k in node.keywords)
            if name == "LocalCluster" or own:
                calls.append((node.lineno, node))
    return calls


def _free_port(call: ast.Call) -> bool:
    """True when the call gives its scheduler a free HTTP port: scheduler_kwargs=NO_HTTP_PORT, or
    dashboard_address=":0"."""
    for kw in call.keywords:
        if kw.arg == "scheduler_kwargs" and isinstance(kw.value, ast.Name) and kw.value.id == "NO_HTTP_PORT":
            return True
        if kw.arg == "dashboard_address" and isinstance(kw.value, ast.Constant) and kw.value.value == ":0":
            return True
    return False


def test_every_local_cluster_takes_a_free_http_port():
    found, wrong = 0, []
    for folder in ("src", "tests", "benchmarks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for line, call in _local_clusters(path):
                found += 1
                if not _free_port(call):
                    wrong.append(f"{path.relative_to(ROOT)}:{line}")
    assert found >= 9  # the runner's and the tests' clusters: the search sees them
    assert wrong == []


def test_the_port_warning_is_an_error_in_the_tests():
    with pytest.raises(UserWarning, match="Port 8787 is already in use"):
        warnings.warn("Port 8787 is already in use.\nPerhaps you already have a cluster running?\n"
                      "Hosting the HTTP server on port 40000 instead")


def test_a_cluster_as_the_tests_start_it_is_quiet_beside_port_8787():
    from distributed import Client, LocalCluster

    from cloudsieve.engine.runner import NO_HTTP_PORT

    taken = socket.socket()
    try:
        try:
            taken.bind(("0.0.0.0", 8787))
            taken.listen()
        except OSError:  # already in use: the case itself
            pass
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster, Client(cluster) as c:
                assert c.submit(sum, [1, 2]).result() == 3
    finally:
        taken.close()
    assert [str(w.message) for w in got if "8787" in str(w.message)] == []
