"""The eliminate rule keeps 1, 10 or 100 points of autzen_trim in the memory of an ordinary run.

Each run is a fresh process (the CLI, ``python -m cloudsieve``, or the in-memory API) started by a wrapper
process that caps its data segment at 1 GiB (RLIMIT_DATA: the heap and private writable mappings, inherited by
every child; not RLIMIT_AS, which numba's LLVM and dask reserve by the gigabyte without using it) and reports
the children's peak resident memory (RUSAGE_CHILDREN's ru_maxrss). An elimination's neighbour lists grow as
(points / kept)^2 in one elimination: at these counts they needed 6 GB and more (core/staged.py runs them in
stages of about half down to 16 times the count, then one elimination keeping 1 in 16: lists no longer than
at 5% kept). A run at 50% kept peaks at about 210-260 MiB in memory and 390 MiB through the work store
(scheduler sync, one process).
"""

from __future__ import annotations

import json
import subprocess
import sys

import laspy
import pytest

from conftest import shared_file

#: the data segment of every process of a run
CAP = 1 << 30
#: the peak resident memory of a run, in KiB
PEAK_KIB = 768 << 10

WRAP = """
import json, resource, subprocess, sys
cap = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_DATA, (cap, cap))
done = subprocess.run(sys.argv[2:], capture_output=True, text=True)
print(json.dumps({"rc": done.returncode, "peak_kib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss,
                  "stdout": done.stdout, "stderr": done.stderr[-3000:]}))
"""


def capped(*args: str) -> dict:
    """Run *args* in a fresh process under the cap: its exit status, peak RSS (KiB), stdout and stderr's end."""
    out = subprocess.run([sys.executable, "-c", WRAP, str(CAP), *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.parametrize("count", [1, 10, 100])
@pytest.mark.parametrize("where", ["memory", "store"])
def test_the_cli_keeps_a_few_points_in_bounded_memory(count, where, tmp_path):
    src, dst = shared_file("autzen_trim.laz"), tmp_path / "o.laz"
    store = ["--scheduler", "sync"] if where == "store" else []  # a scheduler goes through the work store
    run = capped(sys.executable, "-m", "cloudsieve", "simplify", str(src), str(dst), "--count", str(count),
                 "--json", "--no-progress", *store)
    assert run["rc"] == 0, run["stderr"]
    summary = json.loads(run["stdout"])
    assert summary["kept"] == count
    assert summary["scheduler"] == ("sync" if store else "in memory")
    assert laspy.read(str(dst)).header.point_count == count
    assert run["peak_kib"] < PEAK_KIB, run["peak_kib"]


def test_simplify_points_keeps_one_point_in_bounded_memory():
    code = ("import sys, numpy, cloudsieve; xyz = cloudsieve.read_cloud(sys.argv[1])[0]; "
            "kept = cloudsieve.simplify_points(xyz, rule='eliminate', count=1); "
            "print(int(numpy.count_nonzero(kept)) if kept.dtype == bool else len(kept))")
    run = capped(sys.executable, "-c", code, str(shared_file("autzen_trim.laz")))
    assert run["rc"] == 0, run["stderr"]
    assert run["stdout"].split() == ["1"]
    assert run["peak_kib"] < PEAK_KIB, run["peak_kib"]
