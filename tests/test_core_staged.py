"""The ``eliminate`` rule at small kept shares: stages of about half down to 16 times the count (core/staged.py).

Each stage is the reference elimination (tests/eliminate_oracle.py) at its own radius, the last one the
elimination to the count with its relocation; the neighbour lists stay as short as at 5% kept whatever the
count; exact counts, the same result on any thread count, and the shares of 1 in 20 and more run as one
elimination.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cloudsieve.core import eliminate_cells, staged
from cloudsieve.core.eliminate import MIN_CELL_POINTS, eliminate, relocate
from cloudsieve.core.eliminate_cells import eliminate_cell
from cloudsieve.core.elimination import area_radius, keep_lowest
from cloudsieve.core.kernels import neighbours as kn
from cloudsieve.core.staged import LAST_STAGE, STAGED_BELOW, runs_staged, small_share, stage_plan
from eliminate_oracle import eliminate_order


def sheet(n, seed=0, thick=0.02):
    """n random points on a gently curved unit sheet."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return np.c_[u, 0.1 * np.sin(3 * u[:, 0]) + thick * rng.random(n)]


def staged_reference(P, count, r_max, halo=None, kind=None):
    """The stages of core/staged.py with the reference elimination: each stage the points left (the cell's
    and the free halo's) eliminated to their share at the radius of the stage's count with the fixed points
    (and the gone ones in the first stage), down to 16 times the count; the last one the cell's points to
    *count* with the free points left as halo, then the relocation with every kept halo point."""
    hal = np.zeros((0, 3)) if halo is None else halo
    kind = np.zeros(0, dtype=np.uint8) if kind is None else kind
    stages, share = stage_plan(len(P), count)
    own, free = np.arange(len(P)), np.flatnonzero(kind == 1)
    fixed, gone = hal[kind == 2], hal[kind == 0]
    for t in range(1, stages + 1):
        pts = np.concatenate([P[own], hal[free]])
        target = max(1, round(len(pts) * share))
        prio = eliminate_order(pts, r_max=r_max * math.sqrt(count / (len(P) * share**t)), fixed=fixed,
                               gone=gone if t == 1 else None, floor=target)
        keep = keep_lowest(prio, target)
        if keep[: len(own)].sum() < count:
            break
        own, free = own[keep[: len(own)]], free[keep[len(own) :]]
    prio, left = eliminate_order(P[own], r_max=r_max, halo=hal[free], fixed=fixed, floor=count, halo_left=True)
    kept = relocate(P[own], keep_lowest(prio, count), r_max, halo=np.concatenate([fixed, hal[free]]),
                    halo_keep=np.r_[np.ones(len(fixed), dtype=bool), left])
    out = np.zeros(len(P), dtype=bool)
    out[own[kept]] = True
    return out


def test_stage_plan_halves_down_to_16_times_the_count():
    assert LAST_STAGE == 16
    for n, count in [(21, 1), (110_000, 1), (110_000, 110), (519_000, 5_190), (1_000, 49)]:
        stages, share = stage_plan(n, count)
        assert stages == math.ceil(math.log2(n / (16 * count)))
        assert 0.5 <= share < 1
        assert math.isclose(n * share**stages, 16 * count)


def test_only_shares_below_1_in_20_of_the_distinct_points_run_in_stages():
    P = sheet(3_200, seed=1)
    assert STAGED_BELOW == 20
    assert runs_staged(P, 159) and not runs_staged(P, 160)
    copies = np.concatenate([P[:1_600]] * 2)  # 1,600 distinct points: 80 is 1 in 20 of them
    assert runs_staged(copies, 79) and not runs_staged(copies, 80)
    for n in range(1, 5_000):  # a ratio of 0.05 never runs in stages, however it rounds
        assert not small_share(max(1, round(0.05 * n)), n)


@pytest.mark.parametrize("count", [1, 7, 40])
def test_stages_are_the_reference_elimination_at_each_stage_s_radius(count):
    P = sheet(2_000, seed=18)
    P = np.concatenate([P, P[::40]])  # 50 exact copies: the first to go
    r = area_radius(P, np.zeros((0, 3)), count)
    keep = np.zeros(len(P), dtype=bool)
    keep[eliminate(P, count, cell_points=None)] = True
    assert keep.sum() == count
    np.testing.assert_array_equal(keep, staged_reference(P, count, r))


def test_a_cell_s_stages_thin_its_free_halo_with_it_and_weigh_its_fixed_points():
    P = sheet(6_000, seed=4)
    own, halo = P[P[:, 0] < 0.5], P[(P[:, 0] >= 0.5) & (P[:, 0] < 0.9)]
    rng = np.random.default_rng(1)
    kind = rng.choice(np.array([0, 1, 2], dtype=np.uint8), len(halo), p=[0.5, 0.3, 0.2])
    count = 20
    r = area_radius(P, np.zeros((0, 3)), 2 * count)
    keep = eliminate_cell(own, count, r, halo=halo, decided=kind != 1, halo_keep=kind == 2, threads=2)
    assert keep.sum() == count
    np.testing.assert_array_equal(keep, staged_reference(own, count, r, halo, kind))


def test_the_lists_stay_as_short_as_at_5_percent_kept_whatever_the_count(monkeypatch):
    """Neighbour lists of about 3.6 / share entries a point on a plane (7.2 in the stages of about half, 58 in
    the last, which keeps 1 in 16; this sheet's thickness makes it 117 at 5%), on cells of at most 20,480
    points and their halos: no more than one elimination keeping 5% (2,000) lists, where one elimination to
    1 point would list every point in every list."""
    sizes = []
    build = kn.build_lists

    def spy(P, *args, **kw):
        lists = build(P, *args, **kw)
        sizes.append((len(P), int(lists[0][-1])))
        return lists

    monkeypatch.setattr(kn, "build_lists", spy)
    P = sheet(40_000, seed=2)
    for count in (1, 10, 100, 1_000, 2_000):
        sizes.clear()
        assert len(eliminate(P, count, cell_points=MIN_CELL_POINTS)) == count
        assert max(e / n for n, e in sizes) < 125, (count, sizes)
        assert max(e for _, e in sizes) < 2_600_000, (count, sizes)


@pytest.mark.parametrize("count", [1, 10, 300])
def test_exact_counts_and_the_same_points_on_any_thread_count_over_cells(count):
    P = sheet(20_000, seed=6)
    one = eliminate(P, count, cell_points=MIN_CELL_POINTS, threads=1)
    assert len(one) == count
    np.testing.assert_array_equal(one, eliminate(P, count, cell_points=MIN_CELL_POINTS, threads=2))


def test_shares_of_1_in_20_and_more_run_one_elimination(monkeypatch):
    def fail(*args, **kw):
        raise AssertionError("stages run")

    monkeypatch.setattr(staged, "eliminate_staged", fail)
    monkeypatch.setattr(eliminate_cells, "eliminate_staged", fail)
    P = sheet(6_400, seed=3)
    assert len(eliminate(P, 320, cell_points=None)) == 320
    assert eliminate_cell(P, 320, area_radius(P, np.zeros((0, 3)), 320)).sum() == 320


@pytest.mark.parametrize("where", [{}, {"scheduler": "sync"}])
def test_a_run_decides_for_all_its_cells_from_its_own_share(where, tmp_path, monkeypatch):
    """bun_zipper at 5% in 5 cells: three cells keep less than 1 in 20 of their points (4.66-4.95%), the run
    does not, so no cell runs stages (in memory and through the work store alike); at 4.9% every cell does."""
    import cloudsieve
    from conftest import shared_file

    calls = []
    run = staged.eliminate_staged
    monkeypatch.setattr(eliminate_cells, "eliminate_staged", lambda *a, **kw: calls.append(a[2]) or run(*a, **kw))
    src = shared_file("bun_zipper.ply")
    s = cloudsieve.simplify(src, tmp_path / "a.ply", ratio=0.05, cell_size=8_000, **where)
    assert (s.cells, s.kept, calls) == (5, 1_797, [])
    s = cloudsieve.simplify(src, tmp_path / "b.ply", ratio=0.049, cell_size=8_000, **where)
    assert (s.cells, s.kept, len(calls)) == (5, 1_761, 5)
