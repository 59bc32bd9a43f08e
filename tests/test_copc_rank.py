"""COPC of a ranked cloud (store/copc.py, store/octree.py): each voxel keeps its point of lowest ``cloudsieve_rank``.

Against a slow oracle (node by node, voxel by voxel, in Python) on a small
clustered cloud, read back from the written file: its hierarchy and the chunk
of every node. The file is valid (laspy's CopcReader reads every point once,
records exact), the same bytes on 1 or 2 workers and any task size, and a
cloud without the rank keeps the first point of each voxel (PDAL's layout),
its bytes pinned.
"""

from __future__ import annotations

import hashlib
import os
import struct
from collections import defaultdict

import laspy
import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.engine.runner import Runner
from cloudsieve.errors import InvalidParameterError
from cloudsieve.io.rank import RANK_DIM
from cloudsieve.store import PointStore, ingest
from cloudsieve.store.copc import export_copc
from cloudsieve.store.octree import GRID_BITS, KEY_DEPTH, MAX_DEPTH, cells, root_cube

LEAF, TASK = 150, 1_000  # a deep tree and many subtree tasks on 6,000 points


def _cloud(path, rank: np.ndarray | None, n: int = 6_000, seed: int = 5) -> str:
    """A LAS file (format 3) of *n* points, a third in a dense cluster; gps_time = row (identifies a point)."""
    rng = np.random.default_rng(seed)
    xyz = rng.random((n, 3)) * [100.0, 80.0, 20.0]
    xyz[: n // 3] = 40.0 + rng.random((n // 3, 3)) * 3.0
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.zeros(3)
    if rank is not None:
        header.add_extra_dim(laspy.ExtraBytesParams(RANK_DIM, "uint64"))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.gps_time = np.arange(n, dtype=np.float64)
    las.intensity = rng.integers(0, 65535, n).astype(np.uint16)
    if rank is not None:
        las[RANK_DIM] = rank
    las.write(str(path))
    return str(path)


def _store(tmp_path, rank: np.ndarray | None, name: str = "s") -> PointStore:
    return ingest(_cloud(tmp_path / f"{name}.las", rank), tmp_path / f"{name}.zarr", chunk_size=1_700)


def oracle(xyz: np.ndarray, bounds: np.ndarray, rank: np.ndarray, leaf: int) -> dict[tuple, set[int]]:
    """The rows each node (d, x, y, z) keeps, node by node from the root: a node whose cube holds at most *leaf*
    points of the cloud keeps all it receives; another keeps per voxel the point of lowest (rank, row) and sends
    each other point to its child."""
    origin, size = root_cube(bounds)
    c = cells(xyz, origin, size, KEY_DEPTH)
    cube = defaultdict(int)  # points of the cloud in each node's cube
    for d in range(MAX_DEPTH + 1):
        for p in c:
            cube[(d, *(int(v) >> (KEY_DEPTH - d) for v in p))] += 1
    kept: dict[tuple, set[int]] = {}
    level = {(0, 0, 0, 0): list(range(len(xyz)))}
    while level:
        below = defaultdict(list)
        for node, rows in level.items():
            d = node[0]
            if cube[node] <= leaf or d == MAX_DEPTH:
                kept[node] = set(rows)
                continue
            best = {}
            for r in rows:
                voxel = tuple(int(v) >> (KEY_DEPTH - d - GRID_BITS) for v in c[r])
                if voxel not in best or (int(rank[r]), r) < (int(rank[best[voxel]]), best[voxel]):
                    best[voxel] = r
            kept[node] = set(best.values())
            for r in rows:
                if r not in kept[node]:
                    below[(d + 1, *(int(v) >> (KEY_DEPTH - d - 1) for v in c[r]))].append(r)
        level = below
    return kept


def written_nodes(path: str, field: str = "gps_time") -> dict[tuple, set[int]]:
    """The rows (*field*, an integer per point) of each node of a COPC file: its hierarchy's chunks, in file order,
    cut from the points laspy reads through the chunk table."""
    with open(path, "rb") as f:
        f.seek(375 + 54 + 40)  # the info VLR's root hierarchy page: offset, size
        offset, size = struct.unpack("<2Q", f.read(16))
        f.seek(offset)
        table = np.frombuffer(f.read(size), dtype=[("d", "<i4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4"),
                                                   ("offset", "<u8"), ("nbytes", "<i4"), ("count", "<i4")])
    table = table[np.argsort(table["offset"])]
    rows = np.asarray(laspy.read(path)[field]).astype(np.int64)
    ends = np.cumsum(table["count"].astype(np.int64))
    return {(int(e["d"]), int(e["x"]), int(e["y"]), int(e["z"])): set(rows[end - int(e["count"]):end].tolist())
            for e, end in zip(table, ends)}


RANKS = {
    "permutation": lambda n, rng: rng.permutation(n).astype(np.uint64),
    "ties": lambda n, rng: rng.integers(0, 40, n).astype(np.uint64),  # many equal ranks: the row decides
}


@pytest.mark.parametrize("kind", sorted(RANKS))
def test_each_voxel_keeps_its_lowest_rank(kind, tmp_path):
    rank = RANKS[kind](6_000, np.random.default_rng(11))
    store = _store(tmp_path, rank)
    dst = str(tmp_path / "r.copc.laz")
    out = export_copc(store, dst, task_points=TASK, leaf_points=LEAF)
    assert out["ranked"] and out["tasks"] > 4 and out["depth"] >= 4
    got = written_nodes(dst)
    want = oracle(store.read("xyz"), store.bounds, rank, LEAF)
    assert got == want
    # the same tree by first point per voxel is a different one: the rank decides
    assert got != oracle(store.read("xyz"), store.bounds, np.zeros(6_000), LEAF)
    # valid COPC: every point once, records exact, the rank kept as an attribute
    src = laspy.read(tmp_path / "s.las")
    with laspy.CopcReader.open(dst) as reader:
        points = reader.query()
    order = np.argsort(np.asarray(points["gps_time"]))
    np.testing.assert_array_equal(np.asarray(points["gps_time"])[order], np.arange(6_000))
    for name in ("X", "Y", "Z", "intensity", RANK_DIM):
        np.testing.assert_array_equal(np.asarray(points[name])[order], np.asarray(src[name]), err_msg=name)


def test_same_bytes_on_one_or_two_workers_and_any_task_size(tmp_path):
    rank = np.random.default_rng(4).permutation(6_000).astype(np.uint64)
    store = _store(tmp_path, rank)
    paths = [str(tmp_path / f"{i}.copc.laz") for i in range(3)]
    for path, run in ((paths[0], Runner("sync")), (paths[1], Runner("processes", workers=2))):
        try:
            export_copc(store, path, run=run, task_points=TASK, leaf_points=LEAF)
        finally:
            run.close()
    export_copc(store, paths[2], task_points=1_000_000, leaf_points=LEAF)  # one subtree task
    data = [open(p, "rb").read() for p in paths]
    assert data[0] == data[1] == data[2]


def test_rank_false_and_unranked_keep_the_first_point(tmp_path):
    rank = np.random.default_rng(6).permutation(6_000).astype(np.uint64)
    store = _store(tmp_path, rank)
    dst = str(tmp_path / "f.copc.laz")
    assert not export_copc(store, dst, task_points=TASK, leaf_points=LEAF, rank=False)["ranked"]
    first = oracle(store.read("xyz"), store.bounds, np.zeros(6_000), LEAF)
    assert written_nodes(dst) == first
    plain = _store(tmp_path, None, "p")
    dst = str(tmp_path / "p.copc.laz")
    assert not export_copc(plain, dst, task_points=TASK, leaf_points=LEAF)["ranked"]
    assert written_nodes(dst) == first


def test_unranked_scan_pinned_bytes(tmp_path):
    """autzen_trim (no rank) in 16,000-point chunks, 12,000-point tasks, 3,000-point leaves: pinned bytes
    (first point per voxel, PDAL's layout)."""
    store = ingest(shared_file("autzen_trim.laz"), tmp_path / "a.zarr", chunk_size=16_000)
    dst = tmp_path / "a.copc.laz"
    export_copc(store, str(dst), task_points=12_000, leaf_points=3_000)
    assert hashlib.sha256(dst.read_bytes()).hexdigest() == (
        "d9ebfa3790a60e720e32a9fcdf84ce569c72d3dd75941085b28a4684814ec1f1")


def test_rank_asked_without_one(tmp_path):
    plain = _store(tmp_path, None, "p")
    with pytest.raises(InvalidParameterError, match=f"has no {RANK_DIM} attribute to order the octree by: "
                                                     "write one with cloudsieve simplify --rank"):
        export_copc(plain, str(tmp_path / "x.copc.laz"), rank=True)
    with pytest.raises(InvalidParameterError, match="rank must be None, True or False, got 'yes'"):
        export_copc(plain, str(tmp_path / "x.copc.laz"), rank="yes")
    assert not (tmp_path / "x.copc.laz").exists()


def test_simplify_rank_writes_ranked_copc(capsys, tmp_path):
    """``simplify SRC lod.copc.laz --ratio 0.5,0.2 --rank``: COPC files holding the points and ranks of the LAZ
    run, each the COPC of its ranked LAZ (lowest rank per voxel, against the oracle; ``export lod-0.5.laz
    e.copc.laz`` the same bytes), no temporary left."""
    from cloudsieve.cli import main

    src = str(shared_file("autzen_trim.laz"))
    assert main(["simplify", src, str(tmp_path / "lod.laz"), "--ratio", "0.5,0.2", "--rank", "--no-progress"]) == 0
    assert main(["simplify", src, str(tmp_path / "lod.copc.laz"), "--ratio", "0.5,0.2", "--rank",
                 "--no-progress"]) == 0
    assert "ratio 0.2: " + str(tmp_path / "lod-0.2.copc.laz") in capsys.readouterr().out
    assert sorted(os.listdir(tmp_path)) == ["lod-0.2.copc.laz", "lod-0.2.laz", "lod-0.5.copc.laz", "lod-0.5.laz"]
    for ratio in ("0.5", "0.2"):
        laz = laspy.read(tmp_path / f"lod-{ratio}.laz")
        with laspy.CopcReader.open(tmp_path / f"lod-{ratio}.copc.laz") as reader:
            copc = reader.query()
        key = ("X", "Y", "Z", "gps_time", "intensity", RANK_DIM)
        assert sorted(zip(*(np.asarray(laz[k]).tolist() for k in key))) == sorted(
            zip(*(np.asarray(copc[k]).tolist() for k in key)))
    # 55,000 points, 50,000-point leaves: a root sampled by rank, its children leaves
    laz = laspy.read(tmp_path / "lod-0.5.laz")
    written = written_nodes(str(tmp_path / "lod-0.5.copc.laz"), RANK_DIM)
    rows = {int(r): i for i, r in enumerate(laz[RANK_DIM])}
    assert len(rows) == len(laz.points)  # the rank identifies a point
    xyz = np.column_stack([laz.x, laz.y, laz.z])
    bounds = np.stack([xyz.min(axis=0), xyz.max(axis=0)])
    got = {node: {rows[t] for t in kept} for node, kept in written.items()}
    assert len(got) > 1 and got == oracle(xyz, bounds, np.asarray(laz[RANK_DIM]), 50_000)
    # export FILE DST.copc.laz: the ranked file through a temporary store, the same bytes
    assert main(["export", str(tmp_path / "lod-0.5.laz"), str(tmp_path / "e.copc.laz"), "--no-progress"]) == 0
    assert "(each voxel's lowest cloudsieve_rank first)" in capsys.readouterr().err
    assert (tmp_path / "e.copc.laz").read_bytes() == (tmp_path / "lod-0.5.copc.laz").read_bytes()
    assert main(["export", str(tmp_path / "lod-0.5.laz"), str(tmp_path / "m.copc.laz"), "--mask", "k"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"cloudsieve export: error: --mask names a bool array of a point store; {tmp_path / 'lod-0.5.laz'} is a file")
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]  # no temporary left


def test_ranked_copc_refusals_before_any_work(capsys, tmp_path):
    from cloudsieve.cli import main

    src = str(shared_file("autzen_trim.laz"))
    (tmp_path / "o-0.5.copc.laz").write_bytes(b"mine")  # the first output exists: nothing is written
    capsys.readouterr()
    assert main(["simplify", src, str(tmp_path / "o.copc.laz"), "--ratio", "0.5,0.2", "--rank"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith(
        f"cloudsieve simplify: error: {tmp_path / 'o-0.5.copc.laz'} exists")
    assert os.listdir(tmp_path) == ["o-0.5.copc.laz"] and (tmp_path / "o-0.5.copc.laz").read_bytes() == b"mine"
