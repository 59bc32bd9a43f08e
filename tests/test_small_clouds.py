"""Issue 27, item 1: tiny and all-identical clouds out of core give the in-memory answer.

The engine's ``eliminate`` path (``cloudsieve.simplify``) and the in-memory
``simplify_points(..., rule="eliminate")`` keep the same points on a table of
small generated clouds: random clouds of 1 to 20 points (at most 8 points:
no elimination radius), clouds of one spot, and clouds with exact copies,
with and without ``keep_duplicates``. Then the cases of the issue through the
command line: 5,000 identical points keep 1 (every copy with
``--keep-duplicates``), 4 random points keep 2, a NaN cloud with 4 valid
points, and the warning's words.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.io import read_cloud
from cloudsieve.store import PointStore
from test_ops_inputs import run_command


def _random(n, seed):
    return np.random.default_rng(seed).random((n, 3))


def _with_copies(n, seed):
    """*n* points drawn (with repeats) from n // 2 distinct random points."""
    rng = np.random.default_rng(seed)
    base = rng.random((max(1, n // 2), 3))
    return base[rng.integers(0, len(base), n)]


CLOUDS = {
    **{f"random{n}": _random(n, n) for n in range(1, 21)},
    **{f"one-spot{n}": np.full((n, 3), 1.5) for n in (1, 2, 5, 9, 20)},
    **{f"copies{n}": _with_copies(n, n) for n in (4, 7, 12, 20)},
}
TABLE = [(name, ratio, False) for name in CLOUDS for ratio in (0.5, 0.1)] + \
        [(name, 0.5, True) for name in CLOUDS if not name.startswith("random")]


def write_xyz(path, pts):
    np.savetxt(path, pts, fmt="%.17g")  # every bit of the float64 coordinates
    return path


def out_of_core(tmp_path, pts, **options):
    """Indices kept by ``cloudsieve.simplify`` (sync), read from its named work store (kept after success)."""
    src = write_xyz(tmp_path / "in.xyz", pts)
    summary = cloudsieve.simplify(src, tmp_path / "out.xyz", scheduler="sync", store=tmp_path / "work.zarr",
                                  **options)
    keep = np.asarray(PointStore.open(str(tmp_path / "work.zarr"), "r").group["simplify/keep"][:])
    assert summary.kept == int(keep.sum())
    return np.flatnonzero(keep)


@pytest.mark.parametrize("name,ratio,keep_duplicates", TABLE,
                         ids=[f"{n}-{r}{'-keepdup' if k else ''}" for n, r, k in TABLE])
def test_out_of_core_keeps_what_the_in_memory_rule_keeps(tmp_path, name, ratio, keep_duplicates):
    pts = CLOUDS[name]
    expected = cloudsieve.simplify_points(pts, rule="eliminate", ratio=ratio, keep_duplicates=keep_duplicates)
    got = out_of_core(tmp_path, pts, ratio=ratio, keep_duplicates=keep_duplicates)
    np.testing.assert_array_equal(got, expected)
    distinct = len(np.unique(pts, axis=0))
    if not keep_duplicates:  # never empty: min(round(ratio * n), at least 1, distinct points)
        assert len(got) == min(max(1, round(ratio * len(pts))), distinct)


def test_four_random_points_keep_two_in_and_out_of_core(tmp_path):
    pts = _random(4, 0)
    kept = cloudsieve.simplify_points(pts, rule="eliminate", ratio=0.5)
    assert len(kept) == 2
    np.testing.assert_array_equal(out_of_core(tmp_path, pts, ratio=0.5), kept)


def test_half_of_one_point_is_that_point():
    from cloudsieve.core._validation import ratio_count

    assert ratio_count(0.5, 1) == 1 and ratio_count(0.4, 1) == 1 and ratio_count(0.5, 0) == 0
    assert cloudsieve.simplify_points(np.zeros((1, 3)), rule="eliminate", ratio=0.5).tolist() == [0]


# ---------------------------------------------------------------- the command line


def _simplify(argv, capsys):
    capsys.readouterr()
    rc = main(["simplify", *map(str, argv), "--scheduler", "sync", "--no-progress", "--json"])
    out = capsys.readouterr().out
    return rc, json.loads(out) if rc == 0 else None


@pytest.fixture(scope="module")
def one_spot(tmp_path_factory):
    return write_xyz(tmp_path_factory.mktemp("spot") / "ones.xyz", np.ones((5_000, 3)))


def test_identical_points_keep_one(one_spot, tmp_path, capsys):
    rc, summary = _simplify([one_spot, tmp_path / "o.xyz", "--ratio", "0.5"], capsys)
    assert rc == 0
    assert (summary["kept"], summary["duplicates"], summary["duplicates_kept"]) == (1, 4_999, False)
    assert read_cloud(tmp_path / "o.xyz")[0].tolist() == [[1.0, 1.0, 1.0]]


def test_identical_points_keep_every_copy_with_keep_duplicates(one_spot, tmp_path, capsys):
    rc, summary = _simplify([one_spot, tmp_path / "o.xyz", "--ratio", "0.5", "--keep-duplicates"], capsys)
    assert rc == 0
    assert (summary["kept"], summary["duplicates"], summary["duplicates_kept"]) == (5_000, 4_999, True)
    assert len(read_cloud(tmp_path / "o.xyz")[0]) == 5_000


def test_the_warning_of_eliminate_names_the_duplicates_not_thresholds_or_clusters(one_spot, tmp_path):
    rc, err = run_command(["simplify", one_spot, tmp_path / "o.xyz", "--ratio", "0.5", "--scheduler", "sync",
                           "--no-progress"], tmp_path)
    assert rc == 0, err
    warnings = [line for line in err.splitlines() if line.startswith("WARNING")]
    assert warnings == [f"WARNING cloudsieve.engine.simplify: {one_spot}: asked to keep 2,500 points, kept 1: 4,999 "
                        "of the 5,000 points are exact duplicates, kept once (keep_duplicates keeps them)"]
    assert "threshold" not in err and "cluster" not in err and "empty" not in err


def test_a_missed_count_of_an_exact_rule_names_no_threshold():
    from cloudsieve.engine.summary import missed_target

    text = missed_target("a.las", None, 10, 100, 9, exact=True)
    assert text == "a.las: asked to keep 10 points, kept 9: the rule missed its exact count (a bug: please report it " \
                   "with the input)"
    assert "threshold" in missed_target("a.las", None, 10, 100, 9)  # the round rules: equal scores at it


def test_drop_invalid_with_four_valid_points_keeps_two(tmp_path, capsys):
    pts = np.vstack([_random(4, 5), [[np.nan, 0.0, 0.0]], [[0.0, np.inf, 0.0]]])
    src = tmp_path / "nan.xyz"
    np.savetxt(src, pts, fmt="%.17g")
    rc, summary = _simplify([src, tmp_path / "o.xyz", "--ratio", "0.5", "--drop-invalid"], capsys)
    assert rc == 0
    assert (summary["points_in"], summary["kept"]) == (4, 2)
    expected = cloudsieve.simplify_points(pts[:4], rule="eliminate", ratio=0.5)
    np.testing.assert_array_equal(read_cloud(tmp_path / "o.xyz")[0], pts[expected])
