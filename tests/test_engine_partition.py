"""Partition (stage 2): cells, out-of-core bucketing and halos, on real zarr stores.

Stores are written here with zarr directly in the documented layout (xyz
float64 (N, 3), chunks along points, the "cloudsieve" group attribute), so
these tests exercise the partition alone; the runner is dask's sync scheduler.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import zarr
from scipy.spatial import cKDTree

from cloudsieve import partition as P
from cloudsieve.store import PointStore


def make_store(path, xyz: np.ndarray, chunk_size: int) -> PointStore:
    g = zarr.open_group(str(path), mode="w")
    g.create_array("xyz", data=np.asarray(xyz, dtype=np.float64), chunks=(chunk_size, 3))
    g.attrs.update(
        {
            "cloudsieve": {
                "version": 1,
                "count": len(xyz),
                "bounds": [xyz.min(axis=0).tolist(), xyz.max(axis=0).tolist()],
                "format": "xyz",
                "header": {},
                "dimensions": ["xyz"],
                "chunk_size": chunk_size,
                "complete": True,
            }
        }
    )
    return PointStore.open(str(path), "r+")


def run_sync(func, args, stage):
    return [func(*a) for a in args]


def plane(n, seed=1, side=100.0):
    rng = np.random.default_rng(seed)
    xy = rng.random((n, 2)) * side
    return np.c_[xy + 1000.0, np.full(n, 50.0) + rng.normal(0, 0.01, n)]


@pytest.fixture
def built(tmp_path):
    xyz = plane(12_000)
    st = make_store(tmp_path / "s.zarr", xyz, chunk_size=2_500)
    part = P.build_partition(st, cell_size=1_500, cluster_size=100, seed=3, run=run_sync)
    return xyz, st, part


def test_cells_hold_every_point_exactly_once(built):
    xyz, st, part = built
    assert part.n_cells == math.ceil(len(xyz) / 1_500)
    assert part.counts.sum() == len(xyz)
    labels = np.asarray(st.group["partition/cell"][:])
    assert labels.min() >= 0 and labels.max() < part.n_cells
    assert np.array_equal(np.bincount(labels, minlength=part.n_cells), part.cell_counts)
    # union of the cores, read back through the runs, is the input exactly once,
    # each cell in increasing input index
    seen = []
    for j in range(part.n_cells):
        core = P.read_cell(st.group, part.runs(j))
        idx = np.nonzero(labels == j)[0]
        assert np.array_equal(core, xyz[idx])
        seen.append(idx)
    allidx = np.sort(np.concatenate(seen))
    assert np.array_equal(allidx, np.arange(len(xyz)))


def test_labels_are_the_nearest_centre(built):
    xyz, st, part = built
    labels = np.asarray(st.group["partition/cell"][:])
    d = ((xyz[:, None, :] - part.centers[None]) ** 2).sum(-1)
    assert np.array_equal(labels, d.argmin(axis=1))


def test_ties_go_to_the_lower_index():
    centers = np.array([[0.0, 0, 0], [2.0, 0, 0], [1.0, 5, 0], [-3.0, 0, 0]])
    z = np.array([[1.0, 0, 0], [1.0, 0, 0.5], [-1.5, 0, 0], [0.1, 0, 0]])
    labels, _ = P.label_block(centers, z, margin=0.0)
    assert labels.tolist() == [0, 0, 0, 0]


def test_halo_is_every_point_within_the_margin_of_the_region(built):
    xyz, st, part = built
    labels = np.asarray(st.group["partition/cell"][:])
    c = part.centers
    for i in range(part.n_cells):
        runs = {int(s): part.runs(int(s)) for s in part.halo_sources(i)}
        halo = P.read_halo(st.group, runs, c, i, part.margin)
        # brute force: points of other cells whose bisector distance to cell i <= margin
        other = labels != i
        s = P.halo_distance(xyz[other], c[i], c[labels[other]])
        expect = xyz[other][s <= part.margin]
        assert len(halo) == len(expect)
        key = lambda a: a[np.lexsort(a.T[::-1])]  # noqa: E731
        assert np.array_equal(key(halo), key(expect))
        # completeness: every point of another cell within the margin of a point of
        # cell i (so within the margin of its region) is in the halo (the bisector
        # test is a superset: it may hold a few more, near Voronoi vertices)
        d, _ = cKDTree(xyz[labels == i]).query(xyz[other])
        near = xyz[other][d <= part.margin]
        hs = {tuple(r) for r in halo.tolist()}
        assert all(tuple(r) in hs for r in near.tolist())


def test_margin_is_a_few_knn_radii_of_the_full_cloud(built):
    xyz, st, part = built
    meta = st.attrs[P.PARTITION_ATTR]
    k = meta["k"]
    assert k == max(4, round(math.sqrt(100)))
    # uniform plane of density rho: r_k = sqrt(k / (pi rho))
    rho = len(xyz) / 100.0**2
    expected = math.sqrt(k / (math.pi * rho))
    assert meta["r_k"] == pytest.approx(expected, rel=0.2)
    assert 1.7 < meta["dimension"] < 2.3
    assert part.margin == pytest.approx(P.HALO_RADII * meta["r_k"])


def test_partition_does_not_depend_on_the_store_chunking(tmp_path):
    xyz = plane(9_000, seed=5)
    a = make_store(tmp_path / "a.zarr", xyz, chunk_size=1_000)
    b = make_store(tmp_path / "b.zarr", xyz, chunk_size=4_096)
    pa = P.build_partition(a, cell_size=2_000, cluster_size=100, seed=0, run=run_sync)
    pb = P.build_partition(b, cell_size=2_000, cluster_size=100, seed=0, run=run_sync)
    assert np.array_equal(pa.centers, pb.centers)
    assert np.array_equal(pa.cell_counts, pb.cell_counts)
    for j in range(pa.n_cells):
        assert np.array_equal(P.read_cell(a.group, pa.runs(j)), P.read_cell(b.group, pb.runs(j)))


def test_bucketing_writes_each_row_sorted_by_cell(built):
    xyz, st, part = built
    rows = st.group["partition/xyz"]
    off = part.local_offsets()
    labels = np.asarray(st.group["partition/cell"][:])
    for c in range(part.n_chunks):
        a, b = c * 2_500, min((c + 1) * 2_500, len(xyz))
        row = np.asarray(rows[c, : b - a])
        order = np.argsort(labels[a:b], kind="stable")
        assert np.array_equal(row, xyz[a:b][order])
        assert off[c, -1] == b - a


def test_sample_is_uniform_and_seeded():
    a = P.plan_sample(10_000_000, 10, seed=1)
    b = P.plan_sample(10_000_000, 10, seed=1)
    c = P.plan_sample(10_000_000, 10, seed=2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert len(np.unique(a)) == len(a) == P.sample_size(10_000_000, 10)
    # uniform: each tenth of the index range holds about a tenth of the sample
    h = np.bincount(a // 1_000_000, minlength=10)
    assert np.all(np.abs(h - len(a) / 10) < 5 * math.sqrt(len(a) / 10))
    assert np.array_equal(P.plan_sample(500, 1, 0), np.arange(500))


def test_single_cell(tmp_path):
    xyz = plane(3_000)
    st = make_store(tmp_path / "s.zarr", xyz, chunk_size=1_000)
    part = P.build_partition(st, cell_size=10_000, cluster_size=100, seed=0, run=run_sync)
    assert part.n_cells == 1
    assert np.array_equal(P.read_cell(st.group, part.runs(0)), xyz)
    assert len(part.halo_sources(0)) == 0
