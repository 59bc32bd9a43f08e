"""Issue 13, item 3: exact duplicate points, one policy everywhere.

Exact copies (same x, y, z as a point of lower index) are scored once and
kept at most once by every rule (``keep_duplicates`` keeps every copy of a
kept point instead), counted in the summary and logged; ``evaluate``'s subset
check counts multiplicities. Checked on a real scan (simple.las, 1,065
points, no duplicates) with 10 injected exact duplicate pairs, through the
command line (simplify, evaluate, compare) for every rule, and on the core.
"""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from cloudsieve.cli import main
from cloudsieve.core import exact_copies, first_copies, prune, simplify_points
from cloudsieve.errors import NotASubsetError
from cloudsieve.evaluate.points import PointLevel, point_errors
from cloudsieve.io import read_cloud
from conftest import shared_file
from test_ops_inputs import run_command

RULES = [("threshold", []), ("iterative", []), ("target", ["--ratio", "0.5"]), ("iterative", ["--ratio", "0.5"]),
         ("coverage", ["--ratio", "0.5"]), ("eliminate", ["--ratio", "0.5"])]
N_COPIES = 10


@pytest.fixture(scope="module")
def scan_with_copies(tmp_path_factory):
    """simple.las with 10 of its points appended again, every attribute copied: (path, n original points)."""
    las = laspy.read(shared_file("simple.las"))
    n = len(las.points)
    picked = np.arange(0, n, n // N_COPIES)[:N_COPIES]
    out = laspy.LasData(las.header)
    out.points = las.points[np.concatenate([np.arange(n), picked])]
    path = tmp_path_factory.mktemp("dups") / "simple_dups.las"
    out.write(path)
    return path, n


def run(argv, capsys):
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def copies_in(path) -> int:
    xyz = read_cloud(path)[0]
    return len(xyz) - len(np.unique(xyz, axis=0))


# ---------------------------------------------------------------- the command line


@pytest.mark.parametrize("rule,extra", RULES, ids=[r + ("-ratio" if e else "") for r, e in RULES])
def test_simplify_keeps_each_point_once_and_counts_the_copies(scan_with_copies, tmp_path, capsys, rule, extra):
    src, n = scan_with_copies
    assert copies_in(src) == N_COPIES
    dst = tmp_path / "out.las"
    rc, out, _ = run(["simplify", src, dst, "--rule", rule, *extra, "--scheduler", "sync", "--no-progress", "--json"],
                     capsys)
    assert rc == 0
    summary = json.loads(out)
    assert summary["duplicates"] == N_COPIES and summary["duplicates_kept"] is False
    assert copies_in(dst) == 0
    if extra:  # a ratio of the 1,075 input points: 538 of the 1,065 distinct points
        assert summary["kept"] == round(0.5 * (n + N_COPIES))
    rc, out, err = run(["evaluate", src, dst, "--subset", "--no-surface"], capsys)
    assert rc == 0, err


def test_keep_duplicates_keeps_the_copies_of_kept_points(scan_with_copies, tmp_path, capsys):
    src, _ = scan_with_copies
    dst = tmp_path / "out.las"
    rc, out, _ = run(["simplify", src, dst, "--rule", "coverage", "--ratio", "0.5", "--keep-duplicates",
                      "--scheduler", "sync", "--no-progress", "--json"], capsys)
    assert rc == 0
    summary = json.loads(out)
    assert summary["duplicates"] == N_COPIES and summary["duplicates_kept"] is True
    xyz = read_cloud(dst)[0]
    kept_copies = copies_in(dst)
    assert 0 < kept_copies <= N_COPIES and summary["kept"] == 538 + kept_copies
    # the copies are those of kept points: the input holds each kept copy twice, so this is a subset
    assert run(["evaluate", src, dst, "--subset", "--no-surface"], capsys)[0] == 0
    # the scan without the copies holds each point once: the kept copies are not in it
    rc, _, err = run(["evaluate", shared_file("simple.las"), dst, "--subset", "--no-surface"], capsys)
    assert rc == 2
    assert f"{kept_copies} of {len(xyz)} simplified points are not points of the original" in err
    assert "held 2 times, the original holds it 1 time)" in err


def test_one_log_line_names_the_removed_duplicates(scan_with_copies, tmp_path):
    src, _ = scan_with_copies
    rc, err = run_command(["-v", "simplify", src, tmp_path / "out.las", "--rule", "threshold", "--scheduler", "sync",
                           "--no-progress"], tmp_path)
    assert rc == 0, err
    assert f"INFO cloudsieve.engine.simplify: {N_COPIES} exact duplicates removed" in err.splitlines()


def test_a_count_beyond_the_distinct_points_says_why(scan_with_copies, tmp_path):
    src, n = scan_with_copies
    rc, err = run_command(["simplify", src, tmp_path / "out.las", "--rule", "target", "--count", n + 5,
                           "--scheduler", "sync", "--no-progress"], tmp_path)
    assert rc == 0, err
    assert (f"asked to keep {n + 5:,} points, kept {n:,}: {N_COPIES} of the {n + N_COPIES:,} points are exact "
            "duplicates, kept once (keep_duplicates keeps them)") in err


@pytest.mark.parametrize("keep", [False, True])
def test_compare_runs_every_rule_on_a_scan_with_duplicates(scan_with_copies, tmp_path, capsys, keep):
    src, _ = scan_with_copies
    argv = ["compare", src, "--ratio", "0.5", "--methods", "km,fcm", "--rule", "threshold,iterative,target,coverage",
            "--no-surface", "--report-dir", tmp_path / "report"]
    rc, out, err = run(argv + (["--keep-duplicates"] if keep else []), capsys)
    assert rc == 0, err
    rows = json.loads((tmp_path / "report" / "report.json").read_text())["rows"]
    assert len(rows) == 8 and all(r.get("error") is None for r in rows)


# ---------------------------------------------------------------- the core


def _cloud_with_copies():
    xyz = read_cloud(shared_file("simple.las"))[0]
    picked = np.arange(0, len(xyz), 97)
    return xyz, np.concatenate([xyz, xyz[picked]]), picked


def test_exact_copies_and_first_copies():
    pts = np.array([[1.0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert exact_copies(pts).tolist() == [False, False, True, True, True, False]
    assert first_copies(pts).tolist() == [0, 1, 0, 1, 0, 5]
    assert not exact_copies(np.random.default_rng(0).random((100, 3))).any()


@pytest.mark.parametrize("n, p", [(0, 3), (1, 3), (2000, 1), (20_000, 3), (5000, 4)])
def test_first_copies_equal_the_sort_based_oracle(n, p):
    """The hash table against the obvious grouping: sort the rows, equal neighbours share the first index."""
    rng = np.random.default_rng(n + p)
    pts = np.round(rng.random((n, p)) * 20, 1)  # quantised: many ties on every column, many copies
    if n > 10:
        pts[rng.integers(0, n, n // 5)] = pts[rng.integers(0, n, n // 5)]
        pts[3] = -pts[2] * 0.0  # -0.0 equals 0.0
        pts[2] = 0.0
    order = np.lexsort((np.arange(n), *pts.T[::-1]))
    same = np.r_[False, (pts[order][1:] == pts[order][:-1]).all(axis=1)] if n else np.zeros(0, dtype=bool)
    head = order[np.maximum.accumulate(np.where(~same, np.arange(n), 0))] if n else order
    expected = np.empty(n, dtype=np.int64)
    expected[order] = head
    assert first_copies(pts).tolist() == expected.tolist()
    assert exact_copies(pts).tolist() == (expected != np.arange(n)).tolist()
    if n > 10:
        assert first_copies(pts)[3] == 2


@pytest.mark.parametrize("rule,kw", [("threshold", {}), ("iterative", {}), ("target", {"count": 500}),
                                     ("iterative", {"count": 500}), ("coverage", {"count": 500})])
def test_every_rule_drops_the_copies_only(rule, kw):
    """Same clusters: the copies change nothing but themselves (coverage included, with a count)."""
    xyz, both, picked = _cloud_with_copies()
    n = len(xyz)
    labels = np.arange(n) // 200
    keep_plain = prune(xyz, labels, rule=rule, **kw)
    keep_both = prune(both, np.concatenate([labels, labels[picked]]), rule=rule, **kw)
    assert not keep_both[n:].any()
    np.testing.assert_array_equal(keep_both[:n], keep_plain)
    kept_dup = prune(both, np.concatenate([labels, labels[picked]]), rule=rule, keep_duplicates=True, **kw)
    np.testing.assert_array_equal(kept_dup[:n], keep_plain)
    np.testing.assert_array_equal(kept_dup[n:], keep_plain[picked])


@pytest.mark.parametrize("method", ["km", "fcm"])
@pytest.mark.parametrize("rule,kw", [("threshold", {}), ("iterative", {}), ("target", {"ratio": 0.5}),
                                     ("iterative", {"ratio": 0.5}), ("coverage", {"ratio": 0.5}),
                                     ("eliminate", {"ratio": 0.5})])
def test_no_rule_keeps_two_copies(method, rule, kw):
    _, both, _ = _cloud_with_copies()
    kept = simplify_points(both, method=method, rule=rule, **kw)
    assert not exact_copies(both[kept]).any()


# ---------------------------------------------------------------- evaluate's subset check


def test_subset_check_counts_multiplicities():
    rng = np.random.default_rng(0)
    orig = rng.random((500, 3))
    twice = np.concatenate([orig, orig[:3]])  # points 0, 1, 2 twice
    simp = np.concatenate([orig[:100], orig[:2]])  # points 0 and 1 twice
    report = point_errors(twice, simp, PointLevel(subset=True))
    assert report["subset"] and report["not_in_original"] == 0
    with pytest.raises(NotASubsetError, match=r"^2 of 102 simplified points are not points of the original .*"
                       r"held 2 times, the original holds it 1 time\), but a subset was claimed$"):
        point_errors(orig, simp, PointLevel(subset=True))
    assert point_errors(orig, simp)["not_in_original"] == 2


def test_eliminate_with_keep_duplicates_keeps_the_copies_of_kept_points(scan_with_copies, tmp_path, capsys):
    src, n = scan_with_copies
    dst = tmp_path / "out.las"
    rc, out, _ = run(["simplify", src, dst, "--ratio", "0.5", "--keep-duplicates", "--scheduler", "sync",
                      "--no-progress", "--json"], capsys)
    assert rc == 0
    summary = json.loads(out)
    assert summary["duplicates"] == N_COPIES and summary["duplicates_kept"] is True
    xyz = read_cloud(dst)[0]
    uniq, times = np.unique(xyz, axis=0, return_counts=True)
    assert len(uniq) == round(0.5 * (n + N_COPIES))  # the count is met on distinct points
    src_uniq, src_times = np.unique(read_cloud(src)[0], axis=0, return_counts=True)
    doubled = {tuple(p) for p in src_uniq[src_times == 2]}
    for p, t in zip(uniq, times):  # each kept point comes with all its copies
        assert t == (2 if tuple(p) in doubled else 1)


@pytest.mark.parametrize("rule,extra", RULES, ids=[r + ("-ratio" if e else "") for r, e in RULES])
def test_a_pile_of_copies_is_one_point_for_every_rule(tmp_path, rule, extra):
    """A pile (4,000 points at one spot, as failed returns written at the origin) in a scan of several cells:
    every rule keeps it at most once and meets the count. A pile searched point by point costs its size
    squared (60,000 points at one spot took minutes before the searches went per group of copies)."""
    from engine_data import plane, write_laz

    from cloudsieve.engine import simplify

    xyz = plane(20_000, seed=4)
    xyz[:4_000] = xyz[4_000]  # the pile, at a point of the plane
    src = write_laz(tmp_path / "pile.laz", xyz[np.random.default_rng(5).permutation(len(xyz))])
    kw = {"ratio": 0.5} if extra else {}
    s = simplify(src, tmp_path / "out.laz", rule=rule, cell_size=6_000, scheduler="sync", **kw)
    assert s.duplicates == 4_000 and s.cells > 1
    out = read_cloud(str(tmp_path / "out.laz"))[0]
    assert len(out) == len(np.unique(out, axis=0)) == s.kept
    if extra:
        assert s.kept == 10_000
