"""The eliminate rule out of core: exact counts, determinism, resume, seams, the counts, the CLI.

On the real scans of ../shared/data (skipped when absent) and generated
planes; real zarr stores, dask's local schedulers and a real LocalCluster.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import laspy
import numpy as np
import pytest
from conftest import shared_file
from engine_data import write_laz
from scipy.spatial import cKDTree

from cloudsieve.cli import main
from cloudsieve.core.colours import cell_colours
from cloudsieve.core.eliminate import eliminate
from cloudsieve.core.packing import kept_counts
from cloudsieve.engine import halo as H
from cloudsieve.engine import partition as P
from cloudsieve.engine import simplify
from cloudsieve.engine.halo import read_band_halo, read_halo
from cloudsieve.engine.runs import cell_runs
from cloudsieve.errors import InvalidParameterError
from cloudsieve.store import PointStore
from cloudsieve.engine.runner import NO_HTTP_PORT

KW = dict(rule="eliminate", cell_size=6_000, chunk_size=10_000, seed=3)


def digest(path) -> bytes:
    return Path(path).read_bytes()


def store_arrays(store):
    st = PointStore.open(str(store), "r")
    g = st.group
    return st, np.asarray(g["simplify/keep"][:]), st.read("xyz")


@pytest.fixture(scope="module")
def scan():
    return shared_file("append-bug.laz")  # 37,805 points; one in a hundred isolated


@pytest.fixture(scope="module")
def reference(scan, tmp_path_factory):
    """The synchronous run at 20% over 7 cells, its work store kept."""
    d = tmp_path_factory.mktemp("elim-ref")
    s = simplify(scan, d / "ref.laz", scheduler="sync", ratio=0.2, store=d / "w.zarr", **KW)
    return d / "ref.laz", s, d / "w.zarr"


# ----------------------------------------------------------------- exact count


@pytest.mark.parametrize("cell_size", [50_000, 4_000])
@pytest.mark.parametrize("ratio, count", [(0.2, None), (None, 5_001)])
def test_exact_count_on_one_cell_and_many(scan, tmp_path, cell_size, ratio, count):
    out = tmp_path / "o.laz"
    s = simplify(scan, out, scheduler="threads", workers=2, ratio=ratio, count=count,
                 **{**KW, "cell_size": cell_size})
    want = count if count is not None else int(round(ratio * s.points_in))
    assert s.kept == want
    assert len(laspy.read(str(out)).points) == want
    assert (s.cells == 1) == (cell_size > s.points_in)


def test_count_above_the_points_keeps_all_and_tiny_ratio_keeps_exactly(tmp_path):
    rng = np.random.default_rng(2)
    src = write_laz(tmp_path / "p.laz", np.c_[rng.random((3_000, 2)) * 30 + 1000, np.zeros(3_000)])
    s = simplify(src, tmp_path / "a.laz", rule="eliminate", count=5_000, cell_size=1_000, scheduler="sync")
    assert s.kept == 3_000
    s = simplify(src, tmp_path / "b.laz", rule="eliminate", count=1, cell_size=1_000, scheduler="sync")
    assert s.kept == 1


# ----------------------------------------------------------------- determinism


@pytest.mark.parametrize("scheduler, workers", [("threads", 2), ("processes", 1), ("processes", 2)])
def test_same_bytes_on_every_local_scheduler(reference, scan, tmp_path, scheduler, workers):
    ref, ref_summary, _ = reference
    out = tmp_path / "o.laz"
    s = simplify(scan, out, scheduler=scheduler, workers=workers, ratio=0.2, **KW)
    assert digest(out) == digest(ref)
    assert (s.kept, s.cells) == (ref_summary.kept, ref_summary.cells)
    assert ref_summary.cells >= 5


def test_same_bytes_on_a_local_cluster_with_1_and_2_workers(reference, scan, tmp_path):
    from distributed import Client, LocalCluster

    ref = reference[0]
    for n in (1, 2):
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as c, Client(c) as client:
            out = tmp_path / f"o{n}.laz"
            simplify(scan, out, client=client, ratio=0.2, **KW)
        assert digest(out) == digest(ref)


# ----------------------------------------------------------------- resume


@pytest.mark.parametrize("crash", ["shares", "apply"])
def test_resume_after_a_crash_mid_pass(reference, scan, tmp_path, crash):
    """A store as a crash leaves it (markers half set, the other cells' results garbage) resumes to the same bytes."""
    ref, ref_summary, ref_store = reference
    store = tmp_path / "w.zarr"
    shutil.copytree(ref_store, store)
    g = PointStore.open(str(store), "r+").group
    p = ref_summary.cells
    half = np.arange(p) < p // 2
    regions = np.asarray(g["simplify/regions"][:])
    counts = np.asarray(g["partition/cell_count"][:])
    g["simplify/done"][:] = half.astype(np.uint8) if crash == "apply" else np.zeros(p, np.uint8)
    if crash == "shares":
        g["simplify/scored"][:] = half.astype(np.uint8)
    for j in np.flatnonzero(~half):  # results of the cells not marked: garbage
        a, n = int(regions[j]), int(counts[j])
        g["simplify/keep_cells"][a : a + n] = np.zeros(n, dtype=bool)
        if crash == "shares":
            g["simplify/share"][j : j + 1] = np.full((1, g["simplify/share"].shape[1]), -1.0)
            g["simplify/band_count"][j : j + 1] = np.zeros(1, dtype=np.int64)
    g["simplify/keep"][:] = np.zeros(g["simplify/keep"].shape, dtype=bool)
    out = tmp_path / "resumed.laz"
    s = simplify(scan, out, scheduler="threads", workers=2, ratio=0.2, store=store, resume=True, **KW)
    assert digest(out) == digest(ref)
    done_before = int(half.sum()) if crash == "apply" else 0
    assert (s.cells_reused, s.cells_computed) == (done_before, p - done_before)


def test_resume_over_a_store_of_another_chunk_layout_starts_the_cells_again(reference, scan, tmp_path):
    """A store whose cell-ordered arrays have another chunk (an earlier version's layout) is not trusted, even
    with every cell marked done: the cells run again, to the same bytes."""
    ref, ref_summary, ref_store = reference
    store = tmp_path / "w.zarr"
    shutil.copytree(ref_store, store)
    st = PointStore.open(str(store), "r+")
    kc = st.group["simplify/keep_cells"]
    shape, chunk = kc.shape, kc.chunks[0]
    st.delete_array("simplify/keep_cells")
    st.create_array("simplify/keep_cells", shape=shape, dtype="bool", chunks=(2 * chunk,), fill_value=False)
    st.group["simplify/done"][:] = np.ones(ref_summary.cells, dtype=np.uint8)
    out = tmp_path / "resumed.laz"
    s = simplify(scan, out, scheduler="sync", ratio=0.2, store=store, resume=True, **KW)
    assert digest(out) == digest(ref)
    assert (s.cells_reused, s.cells_computed) == (0, ref_summary.cells)


def test_resume_over_a_store_of_area_model_shares_starts_the_cells_again(reference, scan, tmp_path):
    """A store of the version whose shares came from the k-NN area model ((P, 2): expected, distinct), every cell
    marked done: its shares are not packings, so the cells run again, to the same bytes."""
    ref, ref_summary, ref_store = reference
    store = tmp_path / "w.zarr"
    shutil.copytree(ref_store, store)
    st = PointStore.open(str(store), "r+")
    p = ref_summary.cells
    st.delete_array("simplify/share")
    st.create_array("simplify/share", shape=(p, 2), dtype="float64", chunks=(1, 2), fill_value=1.0)
    st.group["simplify/scored"][:] = np.ones(p, dtype=np.uint8)
    st.group["simplify/done"][:] = np.ones(p, dtype=np.uint8)
    out = tmp_path / "resumed.laz"
    s = simplify(scan, out, scheduler="sync", ratio=0.2, store=store, resume=True, **KW)
    assert digest(out) == digest(ref)
    assert (s.cells_reused, s.cells_computed) == (0, p)


def test_resume_after_a_crash_mid_colour(reference, scan, tmp_path):
    """Pass 2 crashed inside a colour: the lower colours done, half of this one; the rest reruns to the same bytes."""
    ref, ref_summary, ref_store = reference
    store = tmp_path / "w.zarr"
    shutil.copytree(ref_store, store)
    st = PointStore.open(str(store), "r+")
    g = st.group
    part = P.Partition.load(st)
    colours = cell_colours(part.halo_ptr, part.halo_src)
    assert colours.max() >= 1
    c = 1
    mine = np.flatnonzero(colours == c)
    done = (colours < c) | np.isin(np.arange(part.n_cells), mine[: (len(mine) + 1) // 2])
    regions = np.asarray(g["simplify/regions"][:])
    g["simplify/done"][:] = done.astype(np.uint8)
    for j in np.flatnonzero(~done):  # cells not done: garbage (the higher colours never ran)
        a, n = int(regions[j]), int(part.cell_counts[j])
        g["simplify/keep_cells"][a : a + n] = np.ones(n, dtype=bool)
    g["simplify/keep"][:] = np.zeros(g["simplify/keep"].shape, dtype=bool)
    out = tmp_path / "resumed.laz"
    s = simplify(scan, out, scheduler="processes", workers=2, ratio=0.2, store=store, resume=True, **KW)
    assert digest(out) == digest(ref)
    assert (s.cells_reused, s.cells_computed) == (int(done.sum()), int((~done).sum()))


def test_the_stored_bands_give_the_halo_of_the_whole_cells(reference):
    """read_band_halo (the sources' bands) returns read_halo's points, cells and positions, in its order."""
    _, _, ref_store = reference
    st = PointStore.open(str(ref_store), "r")
    g = st.group
    part = P.Partition.load(st)
    regions = np.asarray(g["simplify/regions"][:])
    counts = np.asarray(g["simplify/band_count"][:])
    assert 0 < counts.sum() < part.cell_counts.sum() / 2
    for j in range(part.n_cells):
        src = [int(s) for s in part.halo_sources(j)]
        centers = {j: part.centers[j], **{s: part.centers[s] for s in src}}
        whole = read_halo(g, {s: cell_runs(g, s) for s in src}, centers, j, part.margin, return_index=True)
        band = read_band_halo(g, {s: int(regions[s]) for s in src}, centers, j, part.margin)
        assert len(whole[0]) > 0
        for a, b in zip(whole, band):
            np.testing.assert_array_equal(a, b)


def test_band_mask_is_the_union_of_the_halo_masks():
    """The compiled band (all bisector planes in one pass) against halo_mask plane by plane, with points
    moved onto the margin of a plane."""
    rng = np.random.default_rng(11)
    for trial in range(100):
        centers = {k: rng.random(3) * 100 for k in range(8)}
        z = rng.random((int(rng.integers(0, 2000)), 3)) * 100
        margin = float(rng.random() * 10)
        deps = [int(d) for d in rng.choice(np.arange(1, 8), size=int(rng.integers(0, 7)), replace=False)]
        if len(z) and deps:
            u = (centers[0] - centers[deps[0]]) / np.linalg.norm(centers[0] - centers[deps[0]])
            d = H.halo_distance(z[:50], centers[deps[0]], centers[0])
            z[:50] -= np.outer(d - margin, u)
        expected = np.zeros(len(z), dtype=bool)
        for i in deps:
            expected |= H.halo_mask(z, centers, i, 0, margin)
        np.testing.assert_array_equal(H.band_mask(z, centers, 0, deps, margin), expected)


def test_a_partition_for_another_count_is_not_reused(reference, scan, tmp_path):
    _, _, ref_store = reference
    store = tmp_path / "w.zarr"
    shutil.copytree(ref_store, store)
    meta = PointStore.open(str(store), "r").attrs[P.PARTITION_ATTR]
    simplify(scan, tmp_path / "o.laz", scheduler="sync", ratio=0.5, store=store, overwrite=True, **KW)
    new = PointStore.open(str(store), "r").attrs[P.PARTITION_ATTR]
    assert new["eliminate_target"] == round(0.5 * meta["count"]) != meta["eliminate_target"]
    assert new["r_max"] < meta["r_max"]
    assert new["margin"] >= P.ELIMINATE_RADII * new["r_max"]


# ----------------------------------------------------------------- the core


def test_one_cell_equals_the_core_eliminate(tmp_path):
    """One cell, no halo, the whole cloud as the partition's sample: the same r_max, k-d cells, order, cut and
    relocation."""
    src = shared_file("bun_zipper.ply")  # 35,947 points: the sample is the whole cloud
    store = tmp_path / "w.zarr"
    s = simplify(src, tmp_path / "o.ply", rule="eliminate", ratio=0.3, cell_size=50_000, store=store,
                 scheduler="sync")
    st, keep, xyz = store_arrays(store)
    assert s.cells == 1
    core = eliminate(xyz, ratio=0.3)  # over k-d cells of CELL_POINTS, as the engine's cell
    assert np.array_equal(np.flatnonzero(keep), core)


# ----------------------------------------------------------------- seams


def _border_distance(xyz, labels, centers):
    """Distance of each point to the border of its cell (the nearest bisector plane)."""
    s = np.full(len(xyz), np.inf)
    for i in range(len(centers)):
        other = labels != i
        s[other] = np.minimum(s[other], H.halo_distance(xyz[other], centers[i], centers[labels[other]]))
    return s


def _near_over_interior(keep, near):
    return keep[near].mean() / keep[~near].mean()


def test_no_seam_on_autzen_at_20_percent(tmp_path):
    """Kept density within r_max of the cell borders vs the interior, normalised by the input density.

    autzen_trim's input is denser near these K-means borders, and any
    Poisson-disk set thins dense parts more: the whole cloud eliminated in
    memory (no cells, the same r_max) gives 0.87 there too. The engine must
    match it within 5%: no seam of its own.
    """
    store = tmp_path / "w.zarr"
    s = simplify(shared_file("autzen_trim.laz"), tmp_path / "o.laz", rule="eliminate", ratio=0.2, cell_size=8_000,
                 store=store, scheduler="processes", workers=2)
    assert s.cells >= 12
    st, keep, xyz = store_arrays(store)
    part = P.Partition.load(st)
    dist = _border_distance(xyz, np.asarray(st.group["partition/cell"][:]), part.centers)
    core = np.zeros(len(xyz), dtype=bool)
    core[eliminate(xyz, count=s.kept, r_max=part.r_max, cell_points=None)] = True
    for r in (part.r_max, 2 * part.r_max):
        near = dist < r
        assert near.sum() > 2_000
        engine, memory = _near_over_interior(keep, near), _near_over_interior(core, near)
        assert abs(engine / memory - 1) <= 0.05, (r, engine, memory)
    # no hole at the borders: the point max as in memory within 10% (measured 1.00x)
    assert _point_max(xyz, keep) <= 1.1 * _point_max(xyz, core)


def test_cells_above_cell_points_run_over_k_d_cells_with_no_seam_and_the_same_bytes(tmp_path):
    """Engine cells of about 37,000 points (above CELL_POINTS: each eliminated over k-d cells, the engine
    cell's halo around them): the same bytes on the synchronous and process schedulers, the exact count, and
    the kept density at the engine cells' borders and the point max of one elimination in memory within 5%
    and 10% (no seam between engine cells nor between the k-d cells inside them)."""
    from cloudsieve.core.eliminate import CELL_POINTS

    src, store = shared_file("autzen_trim.laz"), tmp_path / "w.zarr"
    kw = dict(rule="eliminate", ratio=0.2, cell_size=40_000, chunk_size=20_000, seed=3)
    s = simplify(src, tmp_path / "a.laz", store=store, scheduler="sync", **kw)
    simplify(src, tmp_path / "b.laz", scheduler="processes", workers=2, **kw)
    assert digest(tmp_path / "a.laz") == digest(tmp_path / "b.laz")
    st, keep, xyz = store_arrays(store)
    cells = np.asarray(st.group["partition/cell"][:])
    assert s.cells == 3 and np.bincount(cells).min() > CELL_POINTS and keep.sum() == 22_000
    part = P.Partition.load(st)
    core = np.zeros(len(xyz), dtype=bool)
    core[eliminate(xyz, count=s.kept, r_max=part.r_max, cell_points=None)] = True
    near = _border_distance(xyz, cells, part.centers) < 2 * part.r_max
    assert near.sum() > 2_000
    assert abs(_near_over_interior(keep, near) / _near_over_interior(core, near) - 1) <= 0.05
    assert _point_max(xyz, keep) <= 1.1 * _point_max(xyz, core)


def _point_max(xyz, keep):
    """Largest distance from a point of the cloud to the nearest kept point."""
    return float(cKDTree(xyz[keep]).query(xyz)[0].max())


@pytest.mark.parametrize("name, ratio, cell_size, cells", [("autzen_trim.laz", 0.5, 8_000, 14),
                                                          ("bun_zipper.ply", 0.2, 4_000, 9)])
def test_no_hole_at_the_borders(tmp_path, name, ratio, cell_size, cells):
    """The kept set's point max error is the in-memory one's within 10% (measured: 1.00x on autzen_trim at
    50% and 20% in 14 cells, 1.03x on bun_zipper at 20% in 9; before the colour phases 2.40x, 1.18x, 1.46x:
    both sides of a border removed their border points)."""
    store = tmp_path / "w.zarr"
    s = simplify(shared_file(name), tmp_path / "o.laz", rule="eliminate", ratio=ratio, cell_size=cell_size,
                 store=store, scheduler="threads", workers=2)
    assert s.cells == cells
    st, keep, xyz = store_arrays(store)
    assert keep.sum() == round(ratio * len(xyz))
    core = np.zeros(len(xyz), dtype=bool)
    core[eliminate(xyz, count=int(keep.sum()), cell_points=None)] = True
    assert _point_max(xyz, keep) <= 1.1 * _point_max(xyz, core)


@pytest.mark.parametrize("name, ratio, cell_size, cells", [("append-bug.laz", 0.1, 8_000, 5),
                                                          ("pumpAVisualReferenceImage.e57", 0.5, 20_000, 8)])
def test_cells_counts_as_one_elimination_places_its_points(tmp_path, name, ratio, cell_size, cells):
    """Each cell keeps as many points as one elimination over the whole cloud would there: the point RMS and
    max of the kept set are the in-memory one's within 2% and 10% (measured: 1.01x / 1.00x and 1.00x / 0.99x;
    with the counts of the k-NN area model, 1.48x / 15.5x and 1.10x / 1.24x)."""
    store = tmp_path / "w.zarr"
    s = simplify(shared_file(name), tmp_path / "o.laz", rule="eliminate", ratio=ratio, cell_size=cell_size,
                 store=store, scheduler="threads", workers=2)
    assert s.cells == cells
    st, keep, xyz = store_arrays(store)
    one = np.zeros(len(xyz), dtype=bool)
    one[eliminate(xyz, count=int(keep.sum()), cell_points=None)] = True
    d_cells, d_one = cKDTree(xyz[keep]).query(xyz)[0], cKDTree(xyz[one]).query(xyz)[0]
    assert np.sqrt(np.mean(d_cells**2)) <= 1.02 * np.sqrt(np.mean(d_one**2))
    assert d_cells.max() <= 1.1 * d_one.max()


def test_no_seam_on_a_uniform_plane(tmp_path):
    rng = np.random.default_rng(11)
    n = 20_000
    src = write_laz(tmp_path / "plane.laz", np.c_[rng.random((n, 2)) * 100.0, np.zeros(n)])
    store = tmp_path / "w.zarr"
    s = simplify(src, tmp_path / "o.laz", rule="eliminate", ratio=0.2, cell_size=2_500, chunk_size=5_000,
                 store=store, scheduler="threads")
    assert s.cells >= 8 and s.kept == 4_000
    st, keep, xyz = store_arrays(store)
    part = P.Partition.load(st)
    dist = _border_distance(xyz, np.asarray(st.group["partition/cell"][:]), part.centers)
    for r in (part.r_max, 2 * part.r_max):
        near = dist < r
        assert near.sum() > 1_000
        assert abs(_near_over_interior(keep, near) - 1) <= 0.05, r


# ----------------------------------------------------------------- the counts


def test_kept_counts_sum_exactly_to_the_target_within_each_cell():
    rng = np.random.default_rng(3)
    counts = rng.integers(0, 50, 40)
    distinct = counts - rng.integers(0, 3, 40).clip(max=counts)
    expected = rng.random(40) * counts
    for target in (0, 1, 17, int(distinct.sum()) // 2, int(distinct.sum()) - 1, int(distinct.sum()),
                   int(distinct.sum()) + 5, int(counts.sum()), int(counts.sum()) + 9):
        q = kept_counts(expected, distinct, target)
        assert q.sum() == min(target, distinct.sum()), target
        assert (q >= 0).all() and (q <= distinct).all()  # exact copies never fill a count
        assert np.array_equal(q, kept_counts(expected, distinct, target))


def test_kept_counts_follow_the_shares_clip_and_break_ties_by_cell():
    assert kept_counts([1.0, 1.0, 2.0], [5, 5, 5], 5).tolist() == [1, 1, 3]
    assert kept_counts([1.0, 1.0, 1.0], [5, 5, 5], 4).tolist() == [2, 1, 1]
    assert kept_counts([9.0, 1.0, 1.0], [2, 9, 9], 8).tolist() == [2, 3, 3]
    assert kept_counts([0.0, 0.0], [3, 1], 2).tolist() == [2, 0]  # no share: by distinct points
    assert kept_counts([0.0, 0.0], [3, 1], 6).tolist() == [3, 1]  # copies do not fill the count


def test_cli_says_eliminate_needs_a_ratio_or_a_count(tmp_path, capsys):
    src = shared_file("simple.las")
    rc = main(["simplify", str(src), str(tmp_path / "o.laz"), "--rule", "eliminate", "--threshold", "0.01"])
    err = capsys.readouterr().err
    assert rc == 2  # the API's one message (the command line checks nothing itself)
    assert err == "cloudsieve simplify: error: rule 'eliminate' needs a ratio or a count\n"
    assert main(["simplify", str(src), str(tmp_path / "o.laz"), "--rule", "eliminate"]) == 2
    assert capsys.readouterr().err.strip().endswith("rule 'eliminate' needs a ratio or a count")
    assert not (tmp_path / "o.laz").exists()


def test_api_says_eliminate_needs_a_ratio_or_a_count(tmp_path):
    with pytest.raises(InvalidParameterError, match="rule 'eliminate' needs a ratio or a count"):
        simplify(shared_file("simple.las"), tmp_path / "o.laz", rule="eliminate")
