"""First contact: lazy imports, small inputs in the calling process, ``cloudsieve warmup``.

No wall times here: the timings are in the README ("Start-up"). These tests
check what the timings rely on: ``import cloudsieve`` and ``cloudsieve --help``
load no dask, zarr, open3d, pymeshlab or distributed; a small input runs in
the calling process and writes the same bytes as the process pool; the
warm-up of the default rule leaves nothing for the default command to compile.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.core.kernels.compile_log import CompileLog
from cloudsieve.core.warmup import split_targets, warm_up
from cloudsieve.engine import ahead
from cloudsieve.rule_table import TARGETS, targets_of
from cloudsieve.engine.inprocess import IN_PROCESS_POINTS, local_scheduler, source_points

from conftest import shared_file

HEAVY = ("dask", "zarr", "open3d", "pymeshlab", "distributed")
SRC = str(Path(__file__).resolve().parents[1] / "src")


def _run(code: str, cwd=None) -> list[str]:
    """The words *code* prints in a fresh interpreter that imports this checkout's package."""
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env=env, cwd=cwd).stdout.split()


def _loaded_after(code: str) -> list[str]:
    """The HEAVY modules a fresh interpreter holds after running *code*."""
    return _run(f"import sys\n{code}\nprint(' '.join(m for m in {HEAVY!r} if m in sys.modules))")


def test_import_cloudsieve_loads_no_dask_zarr_open3d_pymeshlab():
    assert _loaded_after("import cloudsieve") == []


def test_cli_help_loads_no_dask_zarr_open3d_pymeshlab():
    code = "from cloudsieve.cli import build_parser\nbuild_parser().format_help()"
    assert _loaded_after(code) == []


def test_public_names_resolve_lazily_and_evaluate_stays_the_function():
    import cloudsieve.evaluate.report  # noqa: F401 - the subpackage of the same name, imported first

    assert callable(cloudsieve.evaluate) and cloudsieve.evaluate.__name__ == "evaluate"
    for name in cloudsieve.__all__:
        assert getattr(cloudsieve, name) is not None, name
    assert set(cloudsieve.__all__) <= set(dir(cloudsieve))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        cloudsieve.nope  # noqa: B018


# a named work store: the store's run (without one, the cloud runs in memory, test_engine_small.py)
@pytest.mark.parametrize("name, cell_size", [("simple.las", 200_000), ("autzen_trim.laz", 40_000)])
def test_small_input_in_process_writes_the_same_bytes_as_the_process_pool(name, cell_size, tmp_path):
    src = shared_file(name)
    assert local_scheduler([str(src)]) == "sync"  # below IN_PROCESS_POINTS: the in-process path
    inproc = cloudsieve.simplify(src, tmp_path / "a.laz", ratio=0.5, cell_size=cell_size, store=tmp_path / "a.zarr")
    pooled = cloudsieve.simplify(src, tmp_path / "b.laz", ratio=0.5, cell_size=cell_size, store=tmp_path / "b.zarr",
                                 scheduler="processes", workers=2)
    assert inproc.scheduler == "sync" and pooled.scheduler.startswith("processes")
    assert inproc.cells == pooled.cells >= (3 if cell_size < 100_000 else 1)
    assert inproc.kept == pooled.kept == round(0.5 * inproc.points_in)
    assert (tmp_path / "a.laz").read_bytes() == (tmp_path / "b.laz").read_bytes()


def test_the_in_process_limit_counts_the_headers(tmp_path):
    autzen = str(shared_file("autzen_trim.laz"))
    n = source_points([autzen])
    assert n == 110_000
    assert local_scheduler([autzen], limit=n) == "sync"
    assert local_scheduler([autzen], limit=n - 1) is None
    assert local_scheduler([autzen, autzen], limit=IN_PROCESS_POINTS) == (
        "sync" if 2 * n <= IN_PROCESS_POINTS else None)
    assert source_points([str(tmp_path / "missing.laz")]) is None  # the run itself reports it
    assert source_points([str(shared_file("bun_zipper.ply"))]) == 35_947
    # E57's reader logs the fields it skips at opening: not opened twice, so not counted
    assert source_points([str(shared_file("pumpAVisualReferenceImage.e57"))]) is None


def test_an_in_memory_run_of_several_cells_imports_scipy_spatial_while_it_reads():
    code = ("import sys\n"
            "from cloudsieve.engine.small import import_beside\n"
            "print(import_beside(None, 1000), import_beside(1000, 1000))\n"  # no count; one cell
            "print('scipy' in sys.modules)\n"
            "t = import_beside(1001, 1000)\n"  # two cells
            "t.join()\n"
            "print(t.name.replace(' ', '-'), 'scipy.spatial' in sys.modules, import_beside(1001, 1000))\n")
    assert _run(code) == ["None", "None", "False", "import-scipy.spatial", "True", "None"]


def test_the_in_memory_run_is_told_the_headers_count(tmp_path):
    from cloudsieve.engine.checks import check_run
    from cloudsieve.params import run_record, validate

    autzen = str(shared_file("autzen_trim.laz"))
    opts = validate("simplify", {"ratio": 0.5})
    checked = check_run(autzen, str(tmp_path / "o.laz"), opts, run_record(opts))
    assert checked.in_memory and checked.points == 110_000


def test_targets_of_a_run():
    assert targets_of("eliminate") == ("common", "partition", "eliminate")
    assert targets_of("threshold") == targets_of("iterative") == targets_of(None) == ("common", "partition", "scores")
    assert {t for rule in ("eliminate", "threshold") for t in targets_of(rule)} <= set(TARGETS)


def test_after_the_eliminate_warm_up_the_default_command_compiles_nothing(tmp_path):
    warm_up(targets_of("eliminate"))
    with CompileLog() as log:
        cloudsieve.simplify(shared_file("autzen_trim.laz"), tmp_path / "o.laz", ratio=0.5, scheduler="sync")
    assert dict(log.seconds) == {}


def test_the_default_rule_compiles_each_kernel_once_and_no_k_nn(tmp_path):
    """Each kernel of the default rule's warm-up holds one signature (an int32 index where another call
    passed an int64 compiled the kernel and its callees again: 5 s of the first start), the radius's
    k-NN is scipy's (the compiled k-NN cost 6-7 s), and no kernel of the scores is compiled for a literal
    argument (``_cluster(Pc, 0, ...)`` compiled the k-d tree and the k-NN a second time)."""
    probe = (
        "import sys\n"
        "from numba.core.registry import CPUDispatcher\n"
        "from cloudsieve.core.warmup import warm_up\n"
        "from cloudsieve.rule_table import targets_of\n"
        "def kernels():\n"
        "    return [(n, k, f) for n, mod in list(sys.modules.items()) if n.startswith('cloudsieve')\n"
        "            for k, f in vars(mod).items() if isinstance(f, CPUDispatcher) and f.__module__ == n]\n"
        "warm_up(targets_of('eliminate'))\n"
        "from cloudsieve.core.kernels import knn\n"
        "print(len(knn._chunk.signatures))\n"
        "for n, k, f in kernels():\n"
        "    if len(f.signatures) > 1:\n"
        "        print(n, k, len(f.signatures))\n"
        "warm_up(['scores'])\n"
        "for n, k, f in kernels():\n"
        "    if 'Literal' in str(f.signatures):\n"
        "        print(n, k, f.signatures)\n"
    )
    # an empty cache: a kernel loaded from the cache registers no signature on the kernels it calls
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.splitlines() == ["0"]


def test_an_empty_cache_compiles_the_elimination_ahead_in_a_second_process(tmp_path):
    """Into an empty numba cache, a second process compiles the kernels the run reaches last (the
    elimination's loop among them) while the run compiles the rest (engine/ahead.py): the same bytes as
    a warm run, the loop's cache file written, and no process left when the command returns."""
    import psutil

    src = shared_file("simple.las")
    warm = tmp_path / "warm.las"
    cloudsieve.simplify(src, warm, ratio=0.5, scheduler="sync")
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-m", "cloudsieve", "-v", "simplify", str(src), str(tmp_path / "cold.las"),
                          "--ratio", "0.5"], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert "numba's cache lacks the kernels of eliminate: process" in out.stderr
    assert (tmp_path / "cold.las").read_bytes() == warm.read_bytes()
    assert list((tmp_path / "cache").rglob("eliminate._eliminate-*.nbi"))
    assert not [p for p in psutil.process_iter(["cmdline"]) if ahead.COMPILER in (p.info["cmdline"] or [])]
    from cloudsieve.core.warmup import ahead_parts

    assert ahead_parts(["common", "partition", "eliminate"]) == []  # this process's cache is warm: none


def test_cli_warmup_exits_0_and_names_each_target(capsys):
    assert main(["warmup", "--targets", "common,scores"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("common: ") and "\nscores: " in out and "cloudsieve warmup: " in out
    assert main(["warmup", "--targets", "common", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert list(record["targets"]) == ["common"] and record["seconds"] >= 0 and record["cache"]


def test_warmup_splits_the_targets_between_two_processes_scores_first():
    assert split_targets(TARGETS) == (["scores", "common", "partition", "eliminate"], ["km", "fcm", "rules"])
    assert split_targets(["rules", "common"]) == (["common"], ["rules"])
    assert split_targets(["common", "scores"]) == (["common", "scores"], [])  # one side empty: one process
    assert split_targets(["fcm", "km"]) == (["fcm", "km"], [])


def test_cli_warmup_on_two_processes_reports_every_target_in_order_and_leaves_none(capsys):
    """Every target: the second process compiles (here: loads) km, fcm and rules; one report, in order."""
    import psutil

    assert main(["warmup", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert list(record["targets"]) == list(TARGETS)
    assert all(set(t) == {"seconds", "compile_seconds", "compiled"} for t in record["targets"].values())
    assert not [p for p in psutil.process_iter(["cmdline"]) if ahead.COMPILER in (p.info["cmdline"] or [])]


def test_a_failed_second_process_reports_none():
    """Its targets then compile in the calling process (cloudsieve.cli.warmup)."""
    proc = ahead.start_targets(["nope"])
    assert ahead.report_of(proc) is None and proc.returncode != 0


def test_cli_warmup_refuses_an_unknown_target(capsys):
    assert main(["warmup", "--targets", "common,nope"]) == 2
    assert "nope" in capsys.readouterr().err


_LOADED = "[m for m in {} if m in __import__('sys').modules]"
_UNUSED = _LOADED.format(('scipy', 'yaml', 'requests', 'pyproj'))
#: in a worker: the fork server imports numba (and so scipy and yaml) before its hook (cloudsieve.engine.pool)
_UNUSED_IN_WORKERS = _LOADED.format(('scipy.linalg', 'requests', 'pyproj'))


def test_the_skipped_imports_stay_unloaded_then_import_as_usual():
    megaplot = shared_file("Megaplot.laz")  # its CRS in GeoTIFF keys only: laspy's parse_crs needs pyproj
    code = (
        "import sys\n"
        "from cloudsieve.lean_start import skip_unused_imports, _FINDER\n"
        "skip_unused_imports()\n"
        "import numpy as np, laspy\n"
        "from cloudsieve.core.kernels import grid\n"
        "x = np.arange(12.0).reshape(4, 3)\n"
        "grid.cell_codes(x, x.min(0), 1.0)\n"
        "import numba.np.arraymath as am\n"
        f"print(len({_UNUSED}), _FINDER in sys.meta_path, am._HAVE_BLAS, laspy.copc.requests)\n"
        "from scipy.spatial import cKDTree\n"
        "import importlib.util, scipy.linalg.cython_blas\n"
        "requests = importlib.util.find_spec('requests') is None or bool(__import__('requests'))\n"  # installed?
        f"print(laspy.open({str(megaplot)!r}).header.parse_crs().to_epsg(), cKDTree(x).query(x[:1])[0][0],\n"
        "      float(scipy.linalg.norm(x[1] - x[0])) ** 2, requests)\n"
    )
    assert _run(code) == ["0", "False", "False", "None", "26917", "0.0", "27.0", "True"]


def test_numbas_config_file_still_reads_with_yaml(tmp_path):
    """numba's yaml import is skipped only where no .numba_config.yaml would be read (the working folder)."""
    code = ("import sys\nfrom cloudsieve.lean_start import skip_unused_imports\nskip_unused_imports()\n"
            "import numba\nprint('yaml' in sys.modules, numba.config.DEBUG_CACHE)\n")
    assert _run(code, cwd=tmp_path) == ["False", "0"]
    (tmp_path / ".numba_config.yaml").write_text("debug_cache: 1\n")
    assert _run(code, cwd=tmp_path) == ["True", "1"]


def test_cache_loads_install_no_registries_and_a_later_compile_has_them():
    """The kernels taken from numba's cache run on numba's runtime alone (cloudsieve.lean_start): the same
    result as in this process, numba's array and typed-container registries not imported; a function
    compiled afterwards in that process gets every registry (np.sort, np.cumsum, a typed list)."""
    import hashlib

    import numpy as np

    from cloudsieve.core.kernels import grid

    x = np.random.default_rng(0).random((500, 3))
    expected = hashlib.md5(grid.cell_codes(x, x.min(0), 0.25).tobytes()).hexdigest()  # in the cache from here on
    code = (
        "import hashlib, sys\n"
        "import numpy as np\n"
        "from cloudsieve.lean_start import skip_unused_imports\n"
        "skip_unused_imports()\n"
        "from cloudsieve.core.kernels import grid\n"
        "x = np.random.default_rng(0).random((500, 3))\n"
        "got = hashlib.md5(grid.cell_codes(x, x.min(0), 0.25).tobytes()).hexdigest()\n"
        "print(got, sum(grid.cell_codes.stats.cache_hits.values()),\n"
        "      [m for m in ('numba.np.arraymath', 'numba.typed.typedlist') if m in sys.modules])\n"
        "import numba\n"
        "from numba.typed import List\n"
        "@numba.njit\n"
        "def f(a):\n"
        "    out = List()\n"
        "    for v in np.cumsum(np.sort(a)):\n"
        "        out.append(v)\n"
        "    return out\n"
        "print(list(f(x[:, 0])) == list(np.cumsum(np.sort(x[:, 0]))), 'numba.np.arraymath' in sys.modules)\n"
    )
    assert _run(code) == [expected, "1", "[]", "True", "True"]


def test_the_fork_server_skips_the_unused_imports_for_its_workers():
    code = (
        "from cloudsieve.core.rules import DEFAULT_RULE\n"
        "from cloudsieve.engine.pool import local_pool, start_forkserver, worker_context\n"
        "from cloudsieve.rule_table import targets_of\n"
        "ctx = worker_context()\n"
        "start_forkserver(ctx, targets_of(DEFAULT_RULE))\n"
        "with local_pool(1, ctx) as pool:\n"
        "    print(ctx.get_start_method(), pool.submit(eval, \"__import__('laspy').copc.requests\").result(),\n"
        f"          pool.submit(eval, {_UNUSED_IN_WORKERS!r}).result())\n"
    )
    assert _run(code) == ["forkserver", "None", "[]"]


def _compiled_functions(tree):
    """The functions of a module's syntax tree decorated with numba's njit (bare or called)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            for dec in node.decorator_list:
                target = dec.func if isinstance(dec, ast.Call) else dec
                if getattr(target, "id", getattr(target, "attr", None)) in ("njit", "jit"):
                    yield node


def test_no_compiled_kernel_calls_blas():
    """The premise of skipping numba's BLAS probe (cloudsieve.lean_start): no njit function uses np.dot,
    np.vdot, np.matmul, np.inner, @ or np.linalg (numba would compile them without BLAS)."""
    blas = {"dot", "vdot", "matmul", "inner", "linalg", "outer", "tensordot", "einsum"}
    found, checked = [], 0
    for path in sorted(Path(SRC, "cloudsieve").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for fn in _compiled_functions(tree):
            checked += 1
            for node in ast.walk(fn):
                if isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult) or (
                        isinstance(node, ast.Attribute) and node.attr in blas):
                    found.append(f"{path.name}:{fn.name}:{node.lineno}")
    assert checked > 100 and found == []
