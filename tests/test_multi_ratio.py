"""One run, many ratios: nested outputs (engine/levels.py) and the rank dimension (io/rank.py).

On the real scans: each output a subset of the one before (record for
record); the first the same bytes as a run at its ratio alone; each next
one the same bytes as a run on the output before to its count (the
definition); the same bytes in memory, out of core and on 1 or 2 workers;
the rank's first N_k points are output k, written and read back through
LAS and LAZ; the bad lists refused with exit status 2 before any work.
"""

from __future__ import annotations

import filecmp
import os

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.core._validation import ratio_count
from cloudsieve.engine.levels import level_paths
from cloudsieve.io.rank import RANK_DIM, cut_rank, morton, nested_rows, octree_levels, rank_order
from conftest import shared_file

RATIOS = (0.5, 0.2, 0.1)


def _records(path: str) -> np.ndarray:
    """A cloud's points as rows of bytes: the LAS records, or the PLY's x, y, z."""
    if path.endswith(".ply"):
        return np.ascontiguousarray(cloudsieve.read_cloud(path)[0]).view(np.uint8).reshape(-1, 24)
    return np.ascontiguousarray(laspy.read(path).points.array).view(np.uint8).reshape(-1, laspy.read(
        path).header.point_format.size)


def test_level_paths():
    assert level_paths("out/small.laz", "ratio", (0.5, 0.2, 0.05)) == [
        "out/small-0.5.laz", "out/small-0.2.laz", "out/small-0.05.laz"]
    assert level_paths("small.copc.laz", "ratio", (0.5, 0.25)) == ["small-0.5.copc.laz", "small-0.25.copc.laz"]
    assert level_paths("lod/{count}/cloud.laz", "count", (1_000_000, 100_000)) == [
        "lod/1000000/cloud.laz", "lod/100000/cloud.laz"]
    assert level_paths("s3://b/tiles/", "ratio", (0.5, 0.1), folder=True) == ["s3://b/tiles-0.5", "s3://b/tiles-0.1"]


def test_nested_rows_matches_equal_records_first_to_first():
    a = np.array([[1], [2], [1], [3], [1]], dtype=np.uint8)
    assert nested_rows(a, a[[0, 2, 3]]).tolist() == [0, 2, 3]
    assert nested_rows(a, np.array([[1], [1], [3]], dtype=np.uint8)).tolist() == [0, 2, 3]
    assert nested_rows(a, a[:0]).tolist() == []
    with pytest.raises(cloudsieve.NotASubsetError, match="1 of 2 points are not in the output before"):
        nested_rows(a, np.array([[2], [4]], dtype=np.uint8))


def _slow_morton(xyz: np.ndarray) -> list[int]:
    lo = xyz.min(axis=0)
    span = float((xyz.max(axis=0) - lo).max()) or 1.0
    out = []
    for p in xyz:
        q = [min(int((p[a] - lo[a]) / span * 2**21), 2**21 - 1) for a in range(3)]
        out.append(sum(((q[a] >> b) & 1) << (3 * b + a) for b in range(21) for a in range(3)))
    return out


def test_rank_order_against_slow_oracles():
    rng = np.random.default_rng(3)
    xyz = rng.random((400, 3)) * [100.0, 50.0, 3.0]
    xyz[7] = xyz[3]  # a copy: the same code, in row order
    code = _slow_morton(xyz)
    assert morton(xyz).tolist() == code
    depth = rng.integers(1, 4, len(xyz))
    depth[7] = depth[3]
    level = octree_levels(np.array(code, dtype=np.uint64), -depth)
    for band in (1, 2, 3):
        rows = [i for i in range(len(xyz)) if depth[i] == band]
        for d in range(22):  # the points of levels <= d: the first point of each occupied node of level d
            firsts = {}
            for i in sorted(rows, key=lambda i: (code[i], i)):
                firsts.setdefault(code[i] >> (3 * (21 - d)), i)
            assert sorted(i for i in rows if level[i] <= d) == sorted(firsts.values()), (band, d)
    assert level[7] == 22  # a copy of an earlier point: past the finest level

    def node(i):  # the node's code at the point's level, its bits reversed
        bits = min(3 * level[i], 63)
        return int(format(code[i] >> (63 - bits), f"0{bits}b")[::-1], 2) if bits else 0

    expected = sorted(range(len(xyz)), key=lambda i: (-depth[i], level[i], node(i), i))
    rank = rank_order(depth, xyz)
    assert sorted(range(len(xyz)), key=lambda i: rank[i]) == expected
    assert sorted(rank.tolist()) == list(range(len(xyz)))


@pytest.mark.parametrize("name, ext", [("autzen_trim.laz", ".laz"), ("bun_zipper.ply", ".ply")])
def test_nested_outputs_on_real_scans(name, ext, tmp_path):
    src = str(shared_file(name))
    summary = cloudsieve.simplify(src, tmp_path / f"lod{ext}", ratio=[0.1, 0.5, 0.2])  # any order: largest first
    paths = [str(tmp_path / f"lod-{r:g}{ext}") for r in RATIOS]
    assert [o["destination"] for o in summary.outputs] == paths
    n = summary.points_in
    records = [_records(p) for p in paths]
    assert [len(r) for r in records] == [o["kept"] for o in summary.outputs] == [ratio_count(r, n) for r in RATIOS]
    for before, after in zip(records, records[1:]):  # 10% ⊂ 20% ⊂ 50%, in the same order
        rows = nested_rows(before, after)
        assert np.array_equal(before[rows], after)
    # the first: a run at its ratio alone; each next: the run of the output before to its count
    cloudsieve.simplify(src, tmp_path / f"alone{ext}", ratio=RATIOS[0])
    assert filecmp.cmp(tmp_path / f"alone{ext}", paths[0], shallow=False)
    for before, path, r in zip(paths, paths[1:], RATIOS[1:]):
        cloudsieve.simplify(before, tmp_path / f"next{ext}", count=ratio_count(r, n), overwrite=True)
        assert filecmp.cmp(tmp_path / f"next{ext}", path, shallow=False)
    assert "outputs" not in cloudsieve.simplify(src, tmp_path / f"one{ext}", ratio=0.5).to_dict()


def test_same_bytes_in_memory_out_of_core_and_on_workers(tmp_path):
    src = str(shared_file("autzen_trim.laz"))
    runs = {"memory": {}, "store1": {"store": str(tmp_path / "w1.zarr"), "workers": 1},
            "store2": {"workers": 2, "scheduler": "processes"}}
    for label, options in runs.items():
        summary = cloudsieve.simplify(src, tmp_path / f"{label}.laz", count=[50_000, 20_000, 5_000], **options)
        assert (summary.scheduler == "in memory") == (label == "memory")
    assert os.path.isdir(tmp_path / "w1-20000.zarr")  # a given store: one per output, kept
    for count in (50_000, 20_000, 5_000):
        first = tmp_path / f"memory-{count}.laz"
        for label in ("store1", "store2"):
            assert filecmp.cmp(first, tmp_path / f"{label}-{count}.laz", shallow=False), (label, count)


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_rank_prefixes_are_the_outputs_through_las_and_laz(ext, tmp_path):
    src = str(shared_file("autzen_trim.laz"))
    summary = cloudsieve.simplify(src, tmp_path / f"r{ext}", ratio=RATIOS, rank=True)
    paths = [o["destination"] for o in summary.outputs]
    plain = cloudsieve.simplify(src, tmp_path / f"p{ext}", ratio=RATIOS)
    first = laspy.read(paths[0])
    assert first.point_format.dimension_by_name(RANK_DIM).dtype == np.uint64
    for out, other in zip(summary.outputs, plain.outputs):
        cloud = laspy.read(out["destination"])
        rank = np.asarray(cloud[RANK_DIM])
        assert sorted(rank.tolist()) == list(range(out["kept"]))  # output k: ranks 0 .. N_k - 1
        without = laspy.read(other["destination"])  # the same points as without the rank, in the same order
        assert np.array_equal(cloud.X, without.X) and np.array_equal(cloud.gps_time, without.gps_time)
        # the first output's ranks below N_k: output k's records, rank included
        cut = tmp_path / f"cut{ext}"
        assert cut_rank(paths[0], str(cut), out["kept"], overwrite=True) == out["kept"]
        assert np.array_equal(laspy.read(cut).points.array, cloud.points.array)
        # read back by cloudsieve's reader and through a point store
        _, attrs = cloudsieve.read_cloud(out["destination"])
        assert np.array_equal(np.asarray(attrs[RANK_DIM]).ravel(), rank)
    store = tmp_path / "s.zarr"
    cloudsieve.ingest(paths[0], store)
    cloudsieve.export(store, tmp_path / f"back{ext}")
    assert np.array_equal(laspy.read(tmp_path / f"back{ext}")[RANK_DIM], first[RANK_DIM])
    # a cut between two outputs: the smaller output and the band's lowest codes, every point of it a prefix
    assert main(["export", paths[0], str(tmp_path / "mid.laz"), "--keep-rank", "30000", "--no-progress"]) == 0
    mid = laspy.read(tmp_path / "mid.laz")
    assert len(mid) == 30_000 and set(np.asarray(mid[RANK_DIM]).tolist()) == set(range(30_000))


def test_rank_of_one_ratio(tmp_path):
    src = str(shared_file("autzen_trim.laz"))
    summary = cloudsieve.simplify(src, tmp_path / "one.laz", ratio=0.2, rank=True)
    assert summary.outputs[0]["destination"] == str(tmp_path / "one.laz")
    cloudsieve.simplify(src, tmp_path / "plain.laz", ratio=0.2)
    ranked, plain = laspy.read(tmp_path / "one.laz"), laspy.read(tmp_path / "plain.laz")
    assert np.array_equal(ranked.X, plain.X) and sorted(ranked[RANK_DIM].tolist()) == list(range(len(plain)))


def test_rank_refuses_a_first_output_too_large_to_hold(tmp_path, monkeypatch):
    """The outputs are held whole to rank them: a first output above the in-memory bound is refused before any
    work (the bound lowered to autzen_trim's scale; the message names the bound, the count and the source)."""
    import cloudsieve.engine.small as small

    monkeypatch.setattr(small, "IN_MEMORY_POINTS", 50_000)
    src = str(shared_file("autzen_trim.laz"))
    with pytest.raises(cloudsieve.InvalidParameterError) as exc:
        cloudsieve.simplify(src, tmp_path / "lod.laz", ratio=(0.5, 0.2), rank=True)
    assert str(exc.value) == (f"rank holds the outputs in memory to rank them: at most 50,000 points in the first "
                              f"output, got 55,000 ({src})")
    assert list(tmp_path.iterdir()) == []
    cloudsieve.simplify(src, tmp_path / "ok.laz", ratio=(0.4, 0.2), rank=True)  # 44,000: within the bound


def _fails(argv, capsys, tmp_path) -> str:
    capsys.readouterr()
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse
        rc = exc.code
    assert rc == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_bad_lists_exit_2_before_any_work(capsys, tmp_path):
    src = str(shared_file("autzen_trim.laz"))
    out = str(tmp_path / "o.laz")
    cases = [
        (["--ratio", "0.5,,0.2"], "cloudsieve simplify: error: argument --ratio: not a number or a comma-separated "
                                  "list of numbers: '0.5,,0.2'"),
        (["--ratio", "0.5,x"], "cloudsieve simplify: error: argument --ratio: not a number or a comma-separated "
                               "list of numbers: '0.5,x'"),
        (["--ratio", "0.5,0.2,0.5"], "cloudsieve simplify: error: --ratio lists 0.5 more than once: each output "
                                     "needs its own --ratio"),
        (["--count", "1000,1000"], "cloudsieve simplify: error: --count lists 1000 more than once: each output "
                                   "needs its own --count"),
        (["--ratio", "0.5,1.5"], "cloudsieve simplify: error: --ratio must be a number in (0, 1], got 1.5"),
        (["--ratio", "0.5,0.2", "--count", "100,10"], "cloudsieve simplify: error: give ratio or count, not both "
                                                      "(got ratio=(0.5, 0.2), count=(100, 10))"),
        (["--ratio", "0.5,0.2", "--rule", "iterative"], "cloudsieve simplify: error: a list of ratios (nested "
                                                        "outputs) needs the rule 'eliminate', not 'iterative'"),
        (["--ratio", "0.5,0.2", "--keep-class", "2"], "cloudsieve simplify: error: a list of ratios (nested "
                                                      "outputs) does not take --keep-class: run one --ratio at a "
                                                      "time"),
        (["--ratio", "0.5,0.2", "--max-gap", "3"], "cloudsieve simplify: error: a list of ratios (nested "
                                                   "outputs) does not take --max-gap: run one --ratio at a time"),
        (["--ratio", "0.5", "--rank", "--rule", "target"], "cloudsieve simplify: error: --rank needs the rule "
                                                           "'eliminate', not 'target'"),
    ]
    for flags, message in cases:
        assert _fails(["simplify", src, out, *flags, "--no-progress"], capsys, tmp_path) == message, flags
    xyz = str(tmp_path / "o.xyz")
    assert _fails(["simplify", src, xyz, "--ratio", "0.5,0.2"], capsys, tmp_path) == (
        f"cloudsieve simplify: error: a list of ratios writes LAS, LAZ, COPC, PLY or tiles (each output is the next "
        f"one's source), not xyz: {tmp_path / 'o-0.5.xyz'}")
    assert _fails(["simplify", src, xyz, "--ratio", "0.5", "--rank"], capsys, tmp_path) == (
        f"cloudsieve simplify: error: rank writes local LAS, LAZ or COPC files, not xyz: {xyz}")
    tiles = str(tmp_path / "t")
    assert _fails(["simplify", src, tiles, "--ratio", "0.5,0.2", "--rank", "--tile-size", "500"], capsys, tmp_path) == (
        f"cloudsieve simplify: error: rank writes local LAS, LAZ or COPC files, not tiles: {tiles}-0.5")
    assert _fails(["compare", src, "--ratio", "0.5,0.2"], capsys, tmp_path) == (
        "cloudsieve compare: error: --ratio takes one value here, got [0.5, 0.2] (a list writes nested outputs, "
        "in cloudsieve.simplify)")
    assert os.listdir(tmp_path) == []
    (tmp_path / "o-0.1.laz").write_bytes(b"mine")  # an output after the first exists: nothing is written
    assert _fails(["simplify", src, out, "--ratio", "0.5,0.1"], capsys, tmp_path).startswith(
        f"cloudsieve simplify: error: {tmp_path / 'o-0.1.laz'} exists")
    assert os.listdir(tmp_path) == ["o-0.1.laz"] and (tmp_path / "o-0.1.laz").read_bytes() == b"mine"
    assert _fails(["export", src, str(tmp_path / "k.laz"), "--keep-rank", "10"], capsys, tmp_path) == (
        f"cloudsieve export: error: {src} has no {RANK_DIM} dimension: write one with cloudsieve simplify --rank")


def _points(paths) -> set:
    """The points of LAS/LAZ/COPC files as a set of (X, Y, Z, GPS time)."""
    out = set()
    for path in paths:
        cloud = laspy.read(path)
        out |= set(zip(cloud.X.tolist(), cloud.Y.tolist(), cloud.Z.tolist(), cloud.gps_time.tolist()))
    return out


def test_nested_tiles_and_copc(tmp_path):
    src = str(shared_file("autzen_trim.laz"))
    summary = cloudsieve.simplify(src, tmp_path / "t", ratio=[0.5, 0.2], tile_size=500.0)
    tiles = [sorted(str(p) for p in (tmp_path / f"t-{r}").glob("*.laz")) for r in ("0.5", "0.2")]
    assert [o["destination"] for o in summary.outputs] == [str(tmp_path / "t-0.5"), str(tmp_path / "t-0.2")]
    big, small = _points(tiles[0]), _points(tiles[1])
    assert (len(big), len(small)) == (55_000, 22_000) and small <= big
    summary = cloudsieve.simplify(src, tmp_path / "c.copc.laz", ratio=[0.5, 0.2])
    big, small = (_points([o["destination"]]) for o in summary.outputs)
    assert (len(big), len(small)) == (55_000, 22_000) and small <= big


def test_pipeline_with_a_list_of_ratios(tmp_path):
    from cloudsieve.pipeline import load_pipeline, run_pipeline

    src = str(shared_file("autzen_trim.laz"))
    doc = {"pipeline": [{"type": "readers.las", "filename": src},
                        {"type": "filters.entropy", "ratio": [0.2, 0.5]},
                        {"type": "writers.las", "filename": str(tmp_path / "{stem}-{ratio}.laz")},
                        {"type": "evaluate", "surface": False}]}
    [entry] = run_pipeline(load_pipeline(doc))
    assert entry["output"] == str(tmp_path / "autzen_trim-0.5.laz")
    assert entry["report"]["point"]["simplified_count"] == 55_000
    assert nested_rows(_records(str(tmp_path / "autzen_trim-0.5.laz")),
                       _records(str(tmp_path / "autzen_trim-0.2.laz"))).size == 22_000


def test_one_elimination_at_a_fixed_radius_is_nested_the_relocation_is_not():
    """The kernel's removal order does not depend on the count: without relocation, at one r_max, the kept
    sets are nested; the relocation step after it (and r_max, the cells' counts per count) are why a run at
    each ratio is not (docs/architecture.md, "Nested outputs")."""
    from cloudsieve.core.elimination import area_radius
    from cloudsieve.core.eliminate_cells import eliminate_cell

    xyz = np.asarray(cloudsieve.read_cloud(str(shared_file("bun_zipper.ply")))[0], dtype=np.float64)
    n = len(xyz)
    r_max = area_radius(xyz, xyz, n // 10)
    counts = (n // 2, n // 5, n // 10)
    kept = [eliminate_cell(xyz, q, r_max, steps=0, staged=False) for q in counts]
    assert [int(k.sum()) for k in kept] == list(counts)
    assert all(not (small & ~big).any() for big, small in zip(kept, kept[1:]))
    moved = [eliminate_cell(xyz, q, r_max, steps=1, staged=False) for q in counts]
    assert all((small & ~big).any() for big, small in zip(moved, moved[1:]))
