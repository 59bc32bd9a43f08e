"""The ``eliminate`` rule in memory: exact counts, a brute-force oracle, invariances, halo and fixed points.

``eliminate_order`` (tests/eliminate_oracle.py) is the reference elimination with every option of the kernels:
the brute force checks it, and it checks :func:`eliminate` and :func:`eliminate_cell`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cloudsieve.core.cellgrid import CellGrid
from cloudsieve.core.eliminate import eliminate, relocate
from cloudsieve.core.elimination import COVER_GAMMA, COVER_LAMBDA, COVER_RADIUS, keep_lowest
from cloudsieve.core.eliminate_cells import eliminate_cell
from cloudsieve.core.radius import elimination_radius, point_areas
from cloudsieve.errors import InvalidParameterError, InvalidPointsError
from eliminate_oracle import eliminate_order


def sheet(n, seed=0, thick=0.02):
    """n random points on a gently curved unit sheet."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    z = 0.1 * np.sin(3 * u[:, 0]) + thick * rng.random(n)
    return np.c_[u, z]


def removal_order(prio):
    """Indices in removal order: priority descending, ties lower index first."""
    return np.lexsort((np.arange(len(prio)), -prio))


def oracle(P, r_max, alpha, coverage, floor=0):
    """Brute force: every key recomputed from scratch after every removal (plain numpy).

    Returns the removal order, the keys at removal and the largest distance
    from a point to its nearest other remaining point that a coverage key used.
    """
    n = len(P)
    D = np.sqrt(((P[:, None, :] - P[None, :, :]) ** 2).sum(-1))
    two_r = 2 * r_max
    C = np.where(D < two_r, (1 - D / two_r) ** alpha, 0.0)
    np.fill_diagonal(C, 0.0)
    alive = np.ones(n, bool)
    order, keys, reach = [], [], 0.0
    while alive.sum() > floor:
        key = C[:, alive].sum(axis=1)
        if coverage:
            Da = np.where(alive[None, :], D, np.inf)
            near = np.argsort(Da, axis=1, kind="stable")
            a1, a2 = near[:, 0], near[:, 1]  # nearest remaining point, and the next
            d_alt = D[np.arange(n), a2]
            e = np.zeros(n)
            c = np.zeros(n)
            np.maximum.at(e, a1, d_alt)
            np.add.at(c, a1, d_alt**2 - D[np.arange(n), a1] ** 2)
            reach = max(reach, float(d_alt.max()))
            rc = COVER_RADIUS * r_max
            g = np.where(e <= rc, 1.0, (rc / np.maximum(e, rc)) ** COVER_GAMMA)
            key = key * g / (1 + COVER_LAMBDA * c / r_max**2)
        key[~alive] = -1.0
        i = int(np.flatnonzero(key == key.max())[0])
        order.append(i)
        keys.append(key[i])
        alive[i] = False
    return np.array(order), np.array(keys), reach


@pytest.mark.parametrize("alpha", [8.0, 1.0])
def test_plain_order_equals_brute_force(alpha):
    P = sheet(300, seed=1)
    r = 0.04
    prio = eliminate_order(P, r_max=r, alpha=alpha, coverage=False)
    order, keys, _ = oracle(P, r, alpha, coverage=False)
    assert np.array_equal(removal_order(prio), order)
    np.testing.assert_allclose(prio[order], keys, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("seed", [2, 3])
def test_coverage_order_equals_brute_force(seed):
    P = sheet(250, seed=seed)
    r = 0.08
    prio = eliminate_order(P, r_max=r, floor=150)
    order, keys, reach = oracle(P, r, 1.0, coverage=True, floor=150)
    assert reach < 2 * r  # every nearest other point was inside the kernel's search reach
    assert np.array_equal(removal_order(prio)[: len(order)], order)
    np.testing.assert_allclose(prio[order], keys, rtol=1e-12, atol=1e-15)


def test_priorities_non_increasing_and_prefix():
    P = sheet(2000, seed=4)
    prio = eliminate_order(P, ratio=0.3)
    assert np.isfinite(prio).all() and (prio >= 0).all()
    # the removal order is priority descending: stopping at any count is a prefix of it
    o = removal_order(prio)
    assert (np.diff(prio[o]) <= 0).all()
    keep = keep_lowest(prio, 600)
    assert keep.sum() == 600 and not keep[o[:1400]].any()
    # stopping the elimination at the count gives the same kept set
    r = elimination_radius(point_areas(P)[0], 600, weight=point_areas(P)[1])
    assert r > 0
    floor = eliminate_order(P, r_max=r, floor=600)
    assert np.array_equal(keep_lowest(floor, 600), keep_lowest(eliminate_order(P, r_max=r), 600))


def test_floor_counts_the_own_points_only_the_halo_goes_along():
    """With halo, floor=q stops when q of the points are left: the points removed got the keys of the full
    order (the same elimination up to the stop), and keep_lowest(q) keeps exactly the q points left."""
    P = sheet(3000, seed=12)
    core, halo = P[P[:, 0] < 0.6], P[P[:, 0] >= 0.6]
    r = elimination_radius(point_areas(P)[0], 900, weight=point_areas(P)[1])
    full = eliminate_order(core, r_max=r, halo=halo)
    q = 500
    part = eliminate_order(core, r_max=r, halo=halo, floor=q)
    keep = keep_lowest(part, q)
    assert keep.sum() == q
    assert np.array_equal(part[~keep], full[~keep])
    assert part[keep].max() <= part[~keep].min()
    assert (part[keep] >= full[keep]).all()  # keys only fall as points go


@pytest.mark.parametrize("ratio", [1.0, 0.5, 0.2, 0.1, 0.013])
def test_exact_count_for_ratio(ratio):
    P = sheet(3001, seed=5)
    keep = eliminate(P, ratio=ratio)
    assert len(keep) == round(ratio * 3001)
    assert np.array_equal(keep, np.unique(keep))


@pytest.mark.parametrize("count", [1, 2, 777, 2999, 3000])
def test_exact_count_for_count(count):
    P = sheet(3000, seed=6)
    assert len(eliminate(P, count)) == count
    assert len(eliminate(P, count, relocate_steps=0)) == count


def test_count_above_the_points_keeps_them_all_and_unchecked_takes_0():
    """As every surface (params.py knows no cloud size): a count above n keeps the n points; 0 is refused by
    the option's check, and ``eliminate.unchecked`` (the callers that validated) keeps nothing."""
    P = sheet(300, seed=6)
    assert np.array_equal(eliminate(P, 301), np.arange(300))
    assert len(eliminate.unchecked(P, 0)) == 0
    assert np.array_equal(eliminate.unchecked(P, 77), eliminate(P, 77))


def test_point_order_does_not_matter():
    P = sheet(3000, seed=7)
    perm = np.random.default_rng(0).permutation(len(P))
    a = eliminate_order(P, ratio=0.2)
    b = eliminate_order(P[perm], ratio=0.2)
    assert np.array_equal(a[perm], b)  # bit for bit
    ka = eliminate(P, ratio=0.2)
    kb = eliminate(P[perm], ratio=0.2)
    assert np.array_equal(np.sort(perm[kb]), ka)


def test_unit_scale_does_not_matter():
    P = sheet(3000, seed=8) + [10.0, -3.0, 2.0]
    a = eliminate(P, ratio=0.25)
    b = eliminate(P * 1000.0, ratio=0.25)
    assert np.array_equal(a, b)
    pa = eliminate_order(P, ratio=0.25)
    pb = eliminate_order(P * 1000.0, ratio=0.25)
    np.testing.assert_allclose(pa, pb, rtol=1e-9, atol=1e-12)


def test_threads_do_not_matter():
    P = sheet(5000, seed=9)
    a = eliminate_order(P, ratio=0.2, threads=1)
    b = eliminate_order(P, ratio=0.2, threads=2)
    assert np.array_equal(a, b)


def test_duplicates_go_first_and_are_kept_once():
    P = sheet(1000, seed=10)
    dup = np.concatenate([P, P[:200], P[:50]])  # 250 copies of earlier points
    prio = eliminate_order(dup, ratio=0.5)
    assert np.isinf(prio[1000:]).all() and np.isfinite(prio[:1000]).all()
    keep = eliminate(dup, 600)
    assert len(keep) == 600 and keep.max() < 1000  # copies are never kept while distinct points remain
    keep = eliminate(dup, 1100)  # more than the distinct points: the count still holds
    assert len(keep) == 1100
    assert len(np.unique(dup[keep], axis=0)) == 1000


def test_collinear_and_planar_input():
    t = np.linspace(0.0, 1.0, 1001)
    line = np.c_[t, 2 * t, -t]
    keep = eliminate(line, 101)
    assert len(keep) == 101
    gaps = np.diff(t[keep])
    assert gaps.max() <= 3 * gaps.mean()  # no hole: the line stays covered
    rng = np.random.default_rng(11)
    plane = np.c_[rng.random((4000, 2)), np.zeros(4000)]
    keep = eliminate(plane, ratio=0.1)
    assert len(keep) == 400
    d = cKDTree(plane[keep]).query(plane)[0]
    assert d.max() < 2.5 * math.sqrt(1.0 / 400)
    grid = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0), [0.0]), -1).reshape(-1, 3)
    assert len(eliminate(grid, ratio=0.25)) == 400  # a regular grid: ties everywhere, still exact


def test_fixed_points_weigh_but_are_never_removed():
    P = sheet(2000, seed=12)
    fixed = sheet(500, seed=13) * [0.5, 1.0, 1.0]  # denser on the left half
    prio = eliminate_order(P, ratio=0.3, fixed=fixed)
    base = eliminate_order(P, ratio=0.3)
    assert prio.shape == (2000,)
    left = P[:, 0] < 0.45
    # the fixed points crowd the left half: its points go earlier (higher priority)
    k = keep_lowest(prio, 600)
    kb = keep_lowest(base, 600)
    assert k[left].sum() < kb[left].sum()


@pytest.mark.parametrize("seed", [0, 1])
def test_gone_points_continue_the_elimination_where_it_stopped(seed):
    """Stopped at m points, the m left with the removed ones as ``gone`` go on in the same order, same keys."""
    P = sheet(400, seed=20 + seed)
    r_max = 0.04
    full = eliminate_order(P, r_max=r_max)
    order = removal_order(full)
    gone, left = np.sort(order[:250]), np.sort(order[250:])
    prio = eliminate_order(P[left], r_max=r_max, gone=P[gone])
    assert np.array_equal(removal_order(prio), removal_order(full[left]))
    np.testing.assert_allclose(prio, full[left], rtol=1e-12)
    # without them the coverage term does not see the holes they left: another order
    assert not np.array_equal(removal_order(eliminate_order(P[left], r_max=r_max)), removal_order(full[left]))
    # no coverage term: the gone points change nothing
    plain = eliminate_order(P[left], r_max=r_max, coverage=False)
    assert np.array_equal(eliminate_order(P[left], r_max=r_max, gone=P[gone], coverage=False), plain)


def test_copies_of_gone_points_weigh_on_nobody():
    """Exact copies of gone points are not represented (like copies among the points): a pile of copies of
    gone points changes no priority. Represented, each copy added its squared distance to its rep's c(x)."""
    P = sheet(400, seed=22)
    r_max = 0.04
    order = removal_order(eliminate_order(P, r_max=r_max))
    gone, left = np.sort(order[:250]), np.sort(order[250:])
    base = eliminate_order(P[left], r_max=r_max, gone=P[gone])
    piles = np.concatenate([P[gone], np.repeat(P[gone[:5]], 300, axis=0), P[left[:20]]])
    assert np.array_equal(eliminate_order(P[left], r_max=r_max, gone=piles), base)


def test_halo_cells_have_no_seam():
    """Two cells with halos, one global threshold: kept density near the border as inside."""
    rng = np.random.default_rng(14)
    P = np.c_[rng.random((40000, 2)) * [2.0, 1.0], 0.01 * rng.random(40000)]
    n_keep = 4000
    r = elimination_radius(point_areas(P)[0], n_keep, weight=point_areas(P)[1])
    margin = 8 * r
    left = P[:, 0] < 1.0
    prio = np.empty(len(P))
    for cell in (left, ~left):
        near = ~cell & (np.abs(P[:, 0] - 1.0) < margin)
        prio[cell] = eliminate_order(P[cell], r_max=r, halo=P[near])
    keep = keep_lowest(prio, n_keep)
    assert keep.sum() == n_keep
    x = P[keep, 0]
    border = np.abs(x - 1.0) < 4 * r
    inside = (np.abs(x - 0.5) < 4 * r) | (np.abs(x - 1.5) < 4 * r)
    ratio = border.sum() / (inside.sum() / 2)
    assert 0.95 <= ratio <= 1.05, ratio


def test_relocate_keeps_count_and_lowers_error():
    P = sheet(5000, seed=15)
    r = elimination_radius(point_areas(P)[0], 500, weight=point_areas(P)[1])
    keep = keep_lowest(eliminate_order(P, r_max=r), 500)
    moved = relocate(P, keep, r)
    assert moved.sum() == 500
    rms = [np.sqrt((cKDTree(P[k]).query(P)[0] ** 2).mean()) for k in (keep, moved)]
    assert rms[1] <= rms[0]


def test_radius_formula():
    a = np.full(1000, 2.0)
    assert elimination_radius(a, 100) == pytest.approx(math.sqrt(2000 / (2 * math.sqrt(3) * 100)))
    assert elimination_radius(a, 100, weight=10) == pytest.approx(math.sqrt(20000 / (2 * math.sqrt(3) * 100)))
    # 10 isolated points count as one kept point each, not as their huge areas
    b = np.r_[a, np.full(10, 1e9)]
    assert elimination_radius(b, 110) == pytest.approx(elimination_radius(a, 100))
    assert elimination_radius(a, 1000) == math.inf
    # two cells' areas with their own weights, as a driver puts them together
    two = elimination_radius(np.r_[a[:500], a[:250]], 100, weight=np.r_[np.ones(500), np.full(250, 2.0)])
    assert two == pytest.approx(elimination_radius(a, 100))


def test_bad_input():
    P = sheet(100)
    with pytest.raises(InvalidParameterError, match=r"shape \(n, 3\)"):
        eliminate(P[:, :2], 10)
    with pytest.raises(InvalidPointsError, match="index 3"):
        eliminate(np.where(np.arange(100)[:, None] == 3, np.nan, P), 10)
    with pytest.raises(InvalidParameterError, match=r"^give ratio or count, not both \(got ratio=0.1, count=10\)$"):
        eliminate(P, 10, ratio=0.1)
    # the options' messages of every surface (params.py)
    with pytest.raises(InvalidParameterError, match=r"^count must be an integer >= 1, got 0$"):
        eliminate(P, 0)
    with pytest.raises(InvalidParameterError, match=r"^ratio must be a number in \(0, 1\], got 1.5$"):
        eliminate(P, ratio=1.5)
    with pytest.raises(InvalidParameterError, match=r"^rule 'eliminate' needs a ratio or a count$"):
        eliminate(P)
    with pytest.raises(InvalidParameterError, match=r"^relocate_steps must be an integer >= 0, got -1$"):
        eliminate(P, 10, relocate_steps=-1)
    with pytest.raises(InvalidParameterError, match=r"^threads must be an integer >= 1, got 0$"):
        eliminate(P, 10, threads=0)
    with pytest.raises(InvalidParameterError, match="r_max must be a positive number"):
        eliminate(P, 10, r_max=-1.0)
    for gone in ({"halo": P}, {"entropy": 0.5}, {"fixed": P}, {"alpha": 8.0}, {"coverage": False}):
        with pytest.raises(TypeError, match="unexpected keyword argument"):  # the oracle's options, the terms: gone
            eliminate(P, 10, **gone)
    with pytest.raises(ValueError):  # the built-in still catches it
        eliminate(P, -1)


def test_empty_and_tiny():
    assert eliminate(np.zeros((0, 3)), 1).shape == (0,)
    assert eliminate.unchecked(np.zeros((0, 3)), 0).shape == (0,)
    assert eliminate_order(np.zeros((0, 3)), count=0).shape == (0,)
    one = np.zeros((1, 3))
    assert np.array_equal(eliminate(one, 1), [0])
    assert len(eliminate.unchecked(one, 0)) == 0


# sha256 of the priorities (float64 bytes) and of the removal order (int64 bytes) of bun_zipper.ply at the
# r_max of 20% kept, full order, computed with the grid-walk kernel before the neighbour lists, the winner
# tree and the eager coverage bookkeeping (the same priorities bit for bit since), then with the coverage
# factor's fourth power by two squarings instead of pow (kernels/cover.py falloff): 4,869 of the 35,947
# priorities moved by at most 5.8e-16 relative, the removal order the same
BUN20_PRIO = "03dcbf9ed23772460c0f7aebc9831111eca37b29feb495c4d0ecd401076c9363"
BUN20_ORDER = "ffa20db1df751afa2c0b634d16b116d6355745bbaa3c52fc40de981aad1710e7"


def test_priorities_pinned_on_a_real_scan():
    import hashlib

    from conftest import shared_file

    from cloudsieve.io import read_cloud

    P = read_cloud(shared_file("bun_zipper.ply"))[0]
    areas, weight = point_areas(P)
    prio = eliminate_order(P, r_max=elimination_radius(areas, round(0.2 * len(P)), weight=weight))
    assert hashlib.sha256(removal_order(prio).astype(np.int64).tobytes()).hexdigest() == BUN20_ORDER
    assert hashlib.sha256(prio.tobytes()).hexdigest() == BUN20_PRIO


@pytest.mark.parametrize("coverage", [True, False])
def test_floor_keys_are_the_keys_at_the_stop(coverage):
    """Stopped at a floor, the points left get their current keys: the largest is the next removal's."""
    P = sheet(3000, seed=17)
    r = elimination_radius(point_areas(P)[0], 900, weight=point_areas(P)[1])
    full = eliminate_order(P, r_max=r, coverage=coverage)
    part = eliminate_order(P, r_max=r, coverage=coverage, floor=900)
    order = removal_order(full)
    gone = order[:2100]
    assert np.array_equal(part[gone], full[gone])  # the removals: same keys bit for bit
    left = order[2100:]
    assert part[left].max() <= full[gone].min()
    assert removal_order(part)[2100] == order[2100]  # the next removal: the largest key left (ties lower index)
    assert part[order[2100]] == full[order[2100]]
    assert (part[left] >= full[left]).all()  # keys only fall as points go


@pytest.mark.parametrize("ratio", [0.5, 0.1])
def test_eliminate_cell_is_the_elimination_then_relocation(ratio):
    """One cell as the engine runs it: eliminate_order with the decided halo as fixed/gone points, keep_lowest,
    relocate with every kept halo point; eliminate_cell does it on one grid with the same result."""
    from conftest import shared_file

    from cloudsieve.io import read_cloud

    P = read_cloud(shared_file("autzen_trim.laz"))[0]
    x = P[:, 0]
    cut = np.quantile(x, 0.5)
    areas, weight = point_areas(P)
    r_max = float(elimination_radius(areas, int(round(ratio * len(P))), weight=weight))
    core = P[x < cut]
    halo = P[(x >= cut) & (x < cut + 2.2 * r_max)]
    rng = np.random.default_rng(0)
    decided = rng.random(len(halo)) < 0.5
    halo_keep = decided & (rng.random(len(halo)) < ratio)
    count = int(round(ratio * len(core)))
    keep = eliminate_cell(core, count, r_max, halo=halo, decided=decided, halo_keep=halo_keep, threads=2)
    prio, left = eliminate_order(core, r_max=r_max, halo=halo[~decided], fixed=halo[decided & halo_keep],
                                 gone=halo[decided & ~halo_keep], floor=count, halo_left=True)
    hk = halo_keep.copy()
    hk[~decided] = left
    ref = relocate(core, keep_lowest(prio, count), r_max, halo=halo, halo_keep=hk)
    assert keep.sum() == count
    np.testing.assert_array_equal(keep, ref)


def test_eliminate_cell_with_copies_and_lone_points_is_the_elimination_then_relocation():
    """The relocation starts from the elimination's reps (each point's nearest point left); exact copies and
    points with no point left within reach have none and are searched: the same result as from scratch."""
    P = sheet(4000, seed=23)
    P = np.concatenate([P, P[::37], P[:5] + [50.0, 0.0, 0.0]])  # copies; five points far from the rest
    r_max = float(elimination_radius(point_areas(P)[0], 1200, weight=point_areas(P)[1]))
    core, halo = P[P[:, 0] < 0.6], P[P[:, 0] >= 0.6]
    rng = np.random.default_rng(3)
    decided = rng.random(len(halo)) < 0.5
    halo_keep = decided & (rng.random(len(halo)) < 0.3)
    count = 900
    keep = eliminate_cell(core, count, r_max, halo=halo, decided=decided, halo_keep=halo_keep)
    prio, left = eliminate_order(core, r_max=r_max, halo=halo[~decided], fixed=halo[decided & halo_keep],
                                 gone=halo[decided & ~halo_keep], floor=count, halo_left=True)
    hk = halo_keep.copy()
    hk[~decided] = left
    np.testing.assert_array_equal(keep, relocate(core, keep_lowest(prio, count), r_max, halo=halo, halo_keep=hk))


@pytest.mark.parametrize("n, q, sample, piles", [(9, 0, 50, 0), (2000, 0, 50_000, 0), (3000, 400, 1000, 0),
                                                  (500, 300, 200, 0), (3000, 0, 50_000, 1), (3000, 500, 2000, 1)])
def test_point_areas_are_those_of_the_kd_tree(n, q, sample, piles):
    """The areas come from the compiled k-NN kernel: pi r_8^2 / 8 with r_8 cKDTree's 9th distance (self
    included), bit for bit, with copies (a pile of 600 at one spot, groups of 2 to 10 around it), a context
    and sampling."""
    rng = np.random.default_rng(n + q)
    pts = np.round(rng.random((n, 3)) * [50, 50, 3], 1)
    pts[rng.integers(0, n, n // 5)] = pts[rng.integers(0, n, n // 5)]  # exact copies
    if piles:  # searched once per distinct point: a pile, and copies fewer than, as many as, more than k
        pts[:600] = pts[600]
        for size in range(2, 11):
            pts[700 + 20 * size : 700 + 20 * size + size] = pts[699 + 20 * size]
        pts = pts[rng.permutation(n)]
    ctx = np.round(rng.random((q, 3)) * [50, 50, 3], 1)
    areas, weight = point_areas(pts, context=ctx if q else None, sample=sample, seed=5)
    if n + q > sample:  # the seeded sample point_areas documents
        pick = np.sort(np.random.default_rng(5).choice(n + q, sample, replace=False))
        own, rate = pick[pick < n], sample / (n + q)
        allp = np.concatenate([pts[own], ctx[pick[pick >= n] - n]])
    else:
        own, rate, allp = np.arange(n), 1.0, np.concatenate([pts, ctx])
    d = cKDTree(allp).query(allp[: len(own)], k=9)[0][:, 8]
    assert areas.tolist() == (np.pi * np.square(d) / 8 * rate).tolist()
    assert weight == n / len(own)


def _geometry(name: str, n: int, rng) -> np.ndarray:
    """Clouds that take each way of the radius's grid k-NN: a surface (one grid), a volume and a line (the
    first grid's side guessed again), a dense spot (crowded cells on finer grids), far outliers (coarser
    grids, then the few searched against every row), and a lattice (ties at every distance), also at map
    coordinates."""
    u = rng.random((n, 3))
    if name == "surface":
        return np.c_[u[:, :2] * 100, np.sin(u[:, 0] * 6)]
    if name == "volume":
        return u
    if name == "line":
        return np.c_[u[:, 0], np.zeros(n), np.zeros(n)]
    if name == "spot":
        return np.r_[u[: n // 2] * [100, 100, 1], u[n // 2 :] * 0.01 + 50]
    if name == "outliers":
        return np.r_[u[:-100] * [100, 100, 1], u[-100:] * 1e5]
    if name == "utm":  # a lattice at map coordinates: the grid's gaps to skip cells far from its corner's zero
        return np.round(u * [30, 30, 2], 2) + [637_000.0, 849_000.0, 400.0]
    return np.round(u * [30, 30, 2], 1)  # lattice


@pytest.mark.parametrize("name", ["surface", "volume", "line", "spot", "outliers", "lattice", "utm"])
def test_point_areas_on_every_way_of_the_grid_are_the_kd_tree_s(name):
    """The radius's k-NN on the elimination's grids gives cKDTree's 9th distance bit for bit whichever grids
    each point needs (the oracle: scipy's tree)."""
    rng = np.random.default_rng(3)
    pts = np.unique(_geometry(name, 20_000, rng), axis=0)  # copies: test_point_areas_are_those_of_the_kd_tree
    pts = pts[rng.permutation(len(pts))]
    areas, weight = point_areas(pts, sample=len(pts))
    d = cKDTree(pts).query(pts, k=9)[0][:, 8]
    assert areas.tolist() == (np.pi * np.square(d) / 8).tolist()
    assert weight == 1.0


@pytest.mark.parametrize("name", ["surface", "spot", "lattice", "utm"])
def test_nearest_rows_skip_only_cells_beyond_the_kth_distance(name):
    """With the grid's corner and side, the k-NN search skips cells: the same distances, rows and statuses as
    the search of every cell around each row."""
    from cloudsieve.core.kernels.area_knn import nearest_rows

    pts = _geometry(name, 5_000, np.random.default_rng(4))
    for side in (0.3, 1.0, 4.0):
        grid = CellGrid(pts, side)
        rows = np.arange(len(pts))
        every = nearest_rows(*grid.args(), rows, 9, grid.h**2, -1, False)
        skipping = nearest_rows(*grid.args(), rows, 9, grid.h**2, -1, False, 2, grid.lo, grid.h)
        for a, b in zip(every, skipping):
            np.testing.assert_array_equal(a, b)


def test_eliminate_cell_checks_its_masks():
    P = sheet(200)
    with pytest.raises(InvalidParameterError, match=r"decided must be a bool mask of shape \(10,\)"):
        eliminate_cell(P, 50, 0.1, halo=sheet(10, seed=1), decided=np.zeros(9, dtype=bool))


def test_keep_lowest_is_the_lexsort_oracle_with_ties_and_copies():
    """keep_lowest (a partition, or the minimum's entries when they are exactly the count) keeps what sorting by
    (priority, -index) keeps: ties go to higher indices. Half the arrays hold -1.0, as an elimination's points
    left do, the other keys 0 or more."""
    rng = np.random.default_rng(1)
    for t in range(200):
        n = int(rng.integers(1, 50))
        p = rng.integers(0, 5, n).astype(float)
        p[rng.random(n) < 0.2] = np.inf
        if t % 2:
            p[rng.random(n) < 0.4] = -1.0
        for count in range(n + 1):
            ref = np.zeros(n, dtype=bool)
            ref[np.lexsort((-np.arange(n), p))[:count]] = True
            np.testing.assert_array_equal(keep_lowest(p, count), ref)


def test_the_options_and_their_defaults_are_the_specs():
    """eliminate() validates through the one option spec (command ``eliminate``), with its defaults; cell_points
    is optional there (None: one elimination), its default here CELL_POINTS."""
    import inspect

    from cloudsieve.core.eliminate import CELL_POINTS
    from cloudsieve.params import COMMANDS

    sig = inspect.signature(eliminate).parameters
    for name, option in COMMANDS["eliminate"].items():
        assert sig[name].default == (CELL_POINTS if name == "cell_points" else option.default), name


@pytest.mark.parametrize("count", [100, 700, 2049])
def test_eliminate_is_the_reference_elimination_stopped_at_the_count(count):
    """One elimination (cell_points=None) is the reference's order stopped at the count, copies first, then the
    relocation from that kept set (100: the fewest of the 2,000 distinct points kept without stages,
    tests/test_core_staged.py)."""
    from cloudsieve.core.elimination import area_radius

    P = sheet(2000, seed=18)
    P = np.concatenate([P, P[::40]])  # 50 exact copies
    r = area_radius(P, np.zeros((0, 3)), count)
    ref = keep_lowest(eliminate_order(P, r_max=r, floor=count), count)
    keep = np.zeros(len(P), dtype=bool)
    keep[eliminate(P, count, relocate_steps=0, cell_points=None)] = True
    np.testing.assert_array_equal(keep, ref)
    keep[:] = False
    keep[eliminate(P, count, cell_points=None)] = True
    np.testing.assert_array_equal(keep, relocate(P, ref, r))
