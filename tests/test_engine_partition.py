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

from cloudsieve.engine import halo as H
from cloudsieve.engine import label as L
from cloudsieve.engine import partition as P
from cloudsieve.engine import runs as R
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
    assert part.cell_counts.sum() == len(xyz)
    labels = np.asarray(st.group["partition/cell"][:])
    assert labels.min() >= 0 and labels.max() < part.n_cells
    assert np.array_equal(np.bincount(labels, minlength=part.n_cells), part.cell_counts)
    # union of the cores, read back through the runs, is the input exactly once,
    # each cell in increasing input index
    seen = []
    for j in range(part.n_cells):
        core = R.read_runs(st.group, part.runs(j))
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


@pytest.mark.parametrize("margin", [0.0, 0.05, 0.3, 5.0])
def test_labels_and_pairs_equal_a_brute_force_oracle(margin):
    """label_block against every centre's distance: the nearest (ties lower index) and the pairs (i, j) of
    the HALO_NEIGHBOURS + 1 nearest centres of each point of cell j within margin of their bisector."""
    rng = np.random.default_rng(7)
    centers = rng.random((23, 3))
    z = rng.random((3000, 3))
    z[:40] = np.round(z[:40] * 2) / 2  # points equally far from some centres
    centers[:4] = [[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0], [1.0, 1, 0]]
    d = np.sqrt(((z[:, None, :] - centers[None]) ** 2).sum(-1))
    order = np.lexsort((np.broadcast_to(np.arange(len(centers)), d.shape), d), axis=1)
    lab = order[:, 0]
    want = set()
    for r in range(len(z)):
        j = lab[r]
        for i in order[r, 1 : L.HALO_NEIGHBOURS + 1]:
            s = (d[r, i] ** 2 - d[r, j] ** 2) / (2 * np.linalg.norm(centers[i] - centers[j]))
            if s <= margin * (1 + 1e-6) + 1e-12:
                want.add((int(i), int(j)))
    labels, pairs = L.label_block(centers, z, margin)
    assert np.array_equal(labels, lab)
    assert set(map(tuple, pairs.tolist())) == want


def test_ties_go_to_the_lower_index():
    centers = np.array([[0.0, 0, 0], [2.0, 0, 0], [1.0, 5, 0], [-3.0, 0, 0]])
    z = np.array([[1.0, 0, 0], [1.0, 0, 0.5], [-1.5, 0, 0], [0.1, 0, 0]])
    labels, _ = L.label_block(centers, z, margin=0.0)
    assert labels.tolist() == [0, 0, 0, 0]
    labels, pairs = L.label_block(centers, z, margin=0.0, halo=False)
    assert labels.tolist() == [0, 0, 0, 0] and pairs.shape == (0, 2)
    # a three-way tie: the k=2 answer is re-queried
    c3 = np.array([[1.0, 0, 0], [0.0, 1, 0], [-1.0, 0, 0], [0.0, -1, 0]])
    for halo in (True, False):
        assert L.label_block(c3[::-1].copy(), np.zeros((5, 3)), 0.0, halo=halo)[0].tolist() == [0] * 5


def test_partition_without_halo_has_the_same_cells(built, tmp_path):
    xyz, st, part = built
    st2 = make_store(tmp_path / "b.zarr", xyz, chunk_size=2_500)
    part2 = P.build_partition(st2, cell_size=1_500, cluster_size=100, seed=3, run=run_sync, halo=False)
    assert np.array_equal(np.asarray(st.group["partition/cell"][:]), np.asarray(st2.group["partition/cell"][:]))
    for j in range(part.n_cells):
        assert np.array_equal(part.runs(j), part2.runs(j))
        assert len(part2.halo_sources(j)) == 0
    assert st.attrs[P.PARTITION_ATTR]["halo"] and not st2.attrs[P.PARTITION_ATTR]["halo"]


def test_halo_is_every_point_within_the_margin_of_the_region(built):
    xyz, st, part = built
    labels = np.asarray(st.group["partition/cell"][:])
    c = part.centers
    for i in range(part.n_cells):
        runs = {int(s): part.runs(int(s)) for s in part.halo_sources(i)}
        halo = H.read_halo(st.group, runs, c, i, part.margin)
        # brute force: points of other cells whose bisector distance to cell i <= margin
        other = labels != i
        s = H.halo_distance(xyz[other], c[i], c[labels[other]])
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
        assert np.array_equal(R.read_runs(a.group, pa.runs(j)), R.read_runs(b.group, pb.runs(j)))


def test_bucketing_writes_each_row_sorted_by_cell(built):
    xyz, st, part = built
    rows = st.group["partition/xyz"]
    labels = np.asarray(st.group["partition/cell"][:])
    for c in range(part.n_chunks):
        a, b = c * 2_500, min((c + 1) * 2_500, len(xyz))
        row = np.asarray(rows[c, : b - a])
        order = np.argsort(labels[a:b], kind="stable")
        assert np.array_equal(row, xyz[a:b][order])
        assert part.chunk_runs(c)[:, 1].sum() == b - a


def dense_counts(labels, chunk_size, n_cells):
    """The (chunk x cell) table the sparse runs stand for (test oracle only)."""
    chunk = np.arange(len(labels)) // chunk_size
    t = np.zeros((chunk.max() + 1, n_cells), dtype=np.int64)
    np.add.at(t, (chunk, labels), 1)
    return t


def check_run_tables(st, part, labels, chunk_size):
    """Both CSR views hold exactly the nonzero (chunk, cell) runs, with the right offsets."""
    g = st.group
    t = dense_counts(labels, chunk_size, part.n_cells)
    nz_chunk, nz_cell = np.nonzero(t)  # by chunk, cells increasing
    nnz = len(nz_chunk)
    assert part.n_runs == nnz
    # stored: nnz rows, never an n_chunks x P table
    assert g["partition/chunk_runs"].shape == (nnz, 3) and g["partition/cell_runs"].shape == (nnz, 3)
    assert g["partition/chunk_ptr"].shape == (part.n_chunks + 1,) and g["partition/cell_ptr"].shape == (part.n_cells + 1,)
    assert "partition/counts" not in g and "partition/label_runs" not in g
    n = len(labels)
    h = len(part.halo_src)
    for name in g["partition"].array_keys():  # every array is sized by N, P, n_chunks, the runs or the halo pairs
        shape = g["partition"][name].shape
        assert shape[0] in (n, part.n_cells, part.n_cells + 1, part.n_chunks, part.n_chunks + 1, nnz, h, max(h, 1)), (name, shape)
        assert len(shape) == 1 or shape[1] == 3 or (name == "xyz" and shape[1] >= chunk_size), (name, shape)
    by_chunk = np.asarray(g["partition/chunk_runs"][:])
    assert np.array_equal(by_chunk[:, 0], nz_cell) and np.all(by_chunk[:, 1] > 0)
    assert np.array_equal(by_chunk[:, 1], t[nz_chunk, nz_cell])
    within = np.cumsum(t, axis=0) - t  # points of cell j in chunks < c
    assert np.array_equal(by_chunk[:, 2], within[nz_chunk, nz_cell])
    assert np.array_equal(np.asarray(g["partition/chunk_ptr"][:]), np.r_[0, np.cumsum((t > 0).sum(axis=1))])
    local = np.cumsum(t, axis=1) - t  # start of cell j's run in row c
    for j in range(part.n_cells):
        runs = part.runs(j)
        rows = np.nonzero(t[:, j])[0]
        assert np.array_equal(runs[:, 0], rows)
        assert np.array_equal(runs[:, 1], local[rows, j])
        assert np.array_equal(runs[:, 2] - runs[:, 1], t[rows, j])
        assert np.array_equal(runs[:, 3], within[rows, j])
    assert np.array_equal(part.cell_counts, t.sum(axis=0))


def test_run_tables_hold_only_the_nonzero_runs(built):
    xyz, st, part = built
    labels = np.asarray(st.group["partition/cell"][:])
    check_run_tables(st, part, labels, 2_500)


def test_run_tables_built_in_small_blocks_are_the_same(tmp_path, monkeypatch):
    """The run tables written in many small pieces (buffer of 7 runs, zarr chunks of 5) equal the one-piece build."""
    xyz = plane(20_000, seed=9)
    xyz = xyz[np.argsort(xyz[:, 0], kind="stable")]  # coherent order: runs vary in length
    st = make_store(tmp_path / "s.zarr", xyz, chunk_size=1_000)
    part = P.build_partition(st, cell_size=800, cluster_size=100, seed=1, run=run_sync)
    labels = np.asarray(st.group["partition/cell"][:])
    # a spatially coherent input: each chunk touches a few cells only
    assert part.n_runs < 3 * (part.n_chunks + part.n_cells) < part.n_chunks * part.n_cells
    before = {k: np.asarray(st.group[f"partition/{k}"][:]) for k in ("chunk_ptr", "chunk_runs", "cell_ptr", "cell_runs")}
    # rebuild the scratch rows from the labels and index again with a 7-run buffer
    g = st.group
    g.create_array("partition/label_runs", shape=(part.n_chunks, part.n_cells, 2), dtype="int64", chunks=(1, 64, 2))
    t = dense_counts(labels, 1_000, part.n_cells)
    nnz = (t > 0).sum(axis=1)
    for c in range(part.n_chunks):
        cells = np.nonzero(t[c])[0]
        g["partition/label_runs"][c, : len(cells)] = np.stack([cells, t[c, cells]], axis=1)
    monkeypatch.setattr(R, "_RUN_CHUNK", 5)
    R.index_runs(st, nnz, part.n_cells, 1_000, flush=7)
    assert g["partition/cell_runs"].chunks == (5, 3)
    for k, v in before.items():
        assert np.array_equal(np.asarray(g[f"partition/{k}"][:]), v), k
    check_run_tables(st, P.Partition.load(st), labels, 1_000)


def test_shuffled_input_still_partitions_exactly(tmp_path):
    """An incoherent order (every chunk touches most cells): the invariants still hold."""
    xyz = plane(6_000, seed=4)
    xyz = xyz[np.random.default_rng(0).permutation(len(xyz))]
    st = make_store(tmp_path / "s.zarr", xyz, chunk_size=500)
    part = P.build_partition(st, cell_size=1_000, cluster_size=100, seed=2, run=run_sync)
    labels = np.asarray(st.group["partition/cell"][:])
    check_run_tables(st, part, labels, 500)
    for j in range(part.n_cells):
        assert np.array_equal(R.read_runs(st.group, part.runs(j)), xyz[labels == j])


def test_an_older_partition_layout_is_refused_with_a_clear_message(built):
    xyz, st, part = built
    meta = dict(st.attrs[P.PARTITION_ATTR])
    meta["version"] = 1
    st.group.attrs.update({P.PARTITION_ATTR: meta})
    with pytest.raises(P.PartitionLayoutError, match="layout version 1, this cloudsieve reads version 3: partition it again"):
        P.Partition.load(PointStore.open(str(st.path), "r"))


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
    assert np.array_equal(R.read_runs(st.group, part.runs(0)), xyz)
    assert len(part.halo_sources(0)) == 0


@pytest.mark.filterwarnings("ignore::cloudsieve.errors.ConvergenceWarning")  # the centres' fit on this plane
def test_the_sample_taken_while_ingesting_is_the_one_read_from_the_store(tmp_path):
    """IngestSample (the ingest's on_chunk) holds plan_sample's rows of the store, the same coordinates, and
    build_partition given it builds the same cells; None when the reader announced no count (XYZ) or a point
    was dropped, so the partition reads the store as before."""
    from cloudsieve.io import open_writer
    from cloudsieve.store import ingest

    from engine_data import plane as surface

    xyz = surface(120_000, seed=4)
    src = tmp_path / "in.ply"  # a streamed format (LAS sources are ingested by tasks, with no on_chunk)
    with open_writer(src, header={}, dtypes={"xyz": (np.dtype(np.float64), (3,))}) as writer:
        writer.write({"xyz": xyz})
    taken = P.IngestSample(cell_size=2_000, seed=5)
    st = ingest(src, tmp_path / "a.zarr", chunk_size=7_000, on_chunk=taken)
    rows = P.plan_sample(st.count, P.n_cells_for(st.count, 2_000), 5)
    assert 0 < len(rows) < st.count
    stored = st.read("xyz")[rows]
    got = taken.sample(st.count)
    assert got is not None and np.array_equal(got, stored)
    assert taken.sample(st.count - 1) is None
    a = P.build_partition(PointStore.open(st.path, "r+"), cell_size=2_000, cluster_size=100, seed=5, run=run_sync)
    b = P.build_partition(PointStore.open(st.path, "r+"), cell_size=2_000, cluster_size=100, seed=5, run=run_sync,
                          sample=got)
    assert np.array_equal(a.centers, b.centers) and a.margin == b.margin
    assert np.array_equal(a.cell_counts, b.cell_counts)

    txt = tmp_path / "in.xyz"  # no announced count, and a row dropped
    pts = xyz[:5_000].copy()
    pts[10] = np.nan
    np.savetxt(txt, pts)
    taken = P.IngestSample(cell_size=2_000, seed=5)
    st = ingest(txt, tmp_path / "b.zarr", chunk_size=1_000, drop_invalid=True, on_chunk=taken)
    assert st.count == 4_999 and taken.sample(st.count) is None


def test_label_points_on_threads_gives_the_labels_and_pairs_of_one_thread(monkeypatch):
    monkeypatch.setattr(L, "LABEL_BLOCK", 1_000)  # many blocks
    rng = np.random.default_rng(7)
    xyz = rng.random((20_500, 3)) * [100.0, 50.0, 5.0]
    centers = np.ascontiguousarray(xyz[rng.choice(len(xyz), 12, replace=False)])
    one = L.label_points(centers, xyz, 2.0)
    two = L.label_points(centers, xyz, 2.0, threads=2)
    assert one[0].tolist() == two[0].tolist() and one[1].tolist() == two[1].tolist()
    assert len(one[1]) and one[0].tolist() == L.label_block(centers, xyz, 2.0)[0].tolist()
