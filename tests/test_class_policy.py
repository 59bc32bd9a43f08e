"""Class policies of the eliminate rule: ``keep_class`` and ``class_ratio`` on the shared LAS scans.

Oracles: every point of a class kept whole comes out as its exact input
record (the records of that class, in input order, byte for byte); every
other output record is an input record; each class's kept count is the
policy's (round(ratio x points) of the class, or of the points that follow
``ratio``). The same bytes in memory, out of core (a work store, 1 and 2
workers), and the same kept points in tiles and COPC; a run without the
options writes the bytes it wrote before them (pinned records).
"""

from __future__ import annotations

import hashlib
import json

import laspy
import numpy as np
import pytest

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.core._validation import ratio_count
from conftest import shared_file
from resume_data import kill_then_resume
from tiles_data import cut_tiles

LAS_SCANS = ["autzen_trim.laz", "autzen_trim.las", "autzen_trim_7.las", "Megaplot.laz", "append-bug.laz",
             "simple.las", "1_4_w_evlr.laz", "vegetation_1_3.las"]


def records(path) -> tuple[np.ndarray, np.ndarray]:
    """(the raw point records, their classes) of a LAS/LAZ file."""
    las = laspy.read(str(path))
    return las.points.array, np.asarray(las.classification)


def check_policy(src, dst, whole: set, ratios: dict, rest: float) -> None:
    """The oracle: classes in *whole* byte-exact and complete, *ratios* per class exact, the rest at *rest*."""
    rec_in, cls_in = records(src)
    rec_out, cls_out = records(dst)
    assert rec_out.dtype == rec_in.dtype
    for c in whole:
        assert rec_out[cls_out == c].tobytes() == rec_in[cls_in == c].tobytes()
    for c, r in ratios.items():
        assert (cls_out == c).sum() == ratio_count(r, int((cls_in == c).sum()))
    others = ~np.isin(cls_in, [*whole, *ratios])
    assert (~np.isin(cls_out, [*whole, *ratios])).sum() == ratio_count(rest, int(others.sum()))
    # every output record is an input record
    width = rec_in.dtype.itemsize
    as_bytes = {rec_in.tobytes()[i * width:(i + 1) * width] for i in range(len(rec_in))}
    assert all(rec_out.tobytes()[i * width:(i + 1) * width] in as_bytes for i in range(len(rec_out)))


@pytest.mark.parametrize("name", LAS_SCANS)
def test_keep_ground_whole_on_every_las_scan(tmp_path, name):
    src = shared_file(name)
    dst = tmp_path / ("out" + (".las" if name.endswith(".las") else ".laz"))
    summary = cloudsieve.simplify(src, dst, ratio=0.3, keep_class="2", cell_size=20_000)
    check_policy(src, dst, {2}, {}, 0.3)
    _, cls_in = records(src)
    ground = int((cls_in == 2).sum())
    rows = {c["class"]: c for c in summary.classes["classes"]}
    if ground:
        assert rows[2] == {"class": 2, "policy": "whole", "points_in": ground, "kept": ground, "ratio": 1.0}
    assert summary.kept == summary.classes["asked"] == ground + ratio_count(0.3, len(cls_in) - ground)


def test_class_ratios_exact_per_class(tmp_path):
    src = shared_file("append-bug.laz")  # classes 1, 2, 3, 4, 5, 17, 65
    dst = tmp_path / "out.laz"
    summary = cloudsieve.simplify(src, dst, count=5_000, class_ratio="5=0.1,3=0.25,65=1.0", keep_class=[2],
                                  cell_size=10_000)
    _, cls_in = records(src)
    _, cls_out = records(dst)
    for c, r in ((5, 0.1), (3, 0.25)):
        assert (cls_out == c).sum() == ratio_count(r, int((cls_in == c).sum()))
    for c in (2, 65):
        assert (cls_out == c).sum() == (cls_in == c).sum()
    rest = ~np.isin(cls_out, [2, 3, 5, 65])
    assert rest.sum() == min(5_000, int((~np.isin(cls_in, [2, 3, 5, 65])).sum()))
    policies = {p["policy"]: p for p in summary.classes["policies"]}
    assert policies["ratio 0.1"]["classes"] == [5] and policies["whole"]["classes"] == [2, 65]
    assert all(p["kept"] == p["target"] for p in summary.classes["policies"])
    rows = {c["class"]: c for c in summary.classes["classes"]}
    assert sorted(rows) == sorted(np.unique(cls_in).tolist())
    assert all(rows[c]["kept"] == int((cls_out == c).sum()) for c in rows)


def test_same_bytes_in_memory_and_out_of_core(tmp_path):
    src = shared_file("autzen_trim.laz")
    opts = {"ratio": 0.3, "keep_class": "2", "class_ratio": {1: 0.5}, "cell_size": 20_000}
    base = tmp_path / "mem.laz"
    cloudsieve.simplify(src, base, **opts)
    outs = []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}.laz"
        summary = cloudsieve.simplify(src, out, store=tmp_path / f"w{workers}.zarr", workers=workers, **opts)
        assert summary.cells == 6 and summary.scheduler.startswith("processes")
        outs.append(out.read_bytes())
    assert outs[0] == outs[1] == base.read_bytes()
    _, cls = records(src)
    _, out_cls = records(base)
    assert (out_cls == 1).sum() == ratio_count(0.5, int((cls == 1).sum()))


def test_tiles_of_many_files_and_copc(tmp_path):
    src = shared_file("autzen_trim.laz")
    tiles = cut_tiles(src, tmp_path / "in")
    _, cls = records(src)
    ground = int((cls == 2).sum())
    summary = cloudsieve.simplify(tmp_path / "in", tmp_path / "out", ratio=0.2, keep_class="2", tile_size=300,
                                  cell_size=20_000)
    out_cls = np.concatenate([records(p)[1] for p in sorted((tmp_path / "out").glob("*.laz"))])
    assert (out_cls == 2).sum() == ground and len(out_cls) == summary.kept
    assert (out_cls != 2).sum() == ratio_count(0.2, len(cls) - ground)
    # the ground records of the tiles in, byte for byte, in the output tiles
    def ground_records(paths) -> bytes:
        recs = [records(p) for p in paths]
        rec, c = np.concatenate([r for r, _ in recs]), np.concatenate([c for _, c in recs])
        return np.sort(rec[c == 2].view(f"V{rec.dtype.itemsize}")).tobytes()

    assert ground_records(sorted((tmp_path / "out").glob("*.laz"))) == ground_records(tiles)
    copc = tmp_path / "out.copc.laz"
    cloudsieve.simplify(src, copc, ratio=0.2, keep_class="2", cell_size=20_000)
    las = laspy.read(str(copc))
    out = np.asarray(las.classification)
    assert (out == 2).sum() == ground and len(out) == summary.kept
    inp = laspy.read(str(src))
    key = lambda x, y, z: np.sort(np.stack([x, y, z], 1).view("V24").ravel())  # noqa: E731
    assert key(las.X[out == 2] * 1.0, las.Y[out == 2] * 1.0, las.Z[out == 2] * 1.0).tobytes() == \
        key(inp.X[cls == 2] * 1.0, inp.Y[cls == 2] * 1.0, inp.Z[cls == 2] * 1.0).tobytes()


def test_pipeline_keys_and_cli_json(tmp_path, capsys):
    src = shared_file("Megaplot.laz")
    pipe = tmp_path / "p.json"
    pipe.write_text(json.dumps({"pipeline": [
        {"type": "readers.las", "filename": str(src)},
        {"type": "filters.entropy", "ratio": 0.25, "keep_class": [2], "class_ratio": "1=0.1"},
        {"type": "writers.las", "filename": str(tmp_path / "{stem}.laz")}]}))
    assert main(["run", str(pipe), "--no-progress"]) == 0
    _, cls_in = records(src)
    _, cls_out = records(tmp_path / "Megaplot.laz")
    assert (cls_out == 2).sum() == (cls_in == 2).sum()
    assert (cls_out == 1).sum() == ratio_count(0.1, int((cls_in == 1).sum()))
    capsys.readouterr()
    assert main(["simplify", str(src), str(tmp_path / "cli.laz"), "--ratio", "0.25", "--keep-class", "2",
                 "--class-ratio", "1=0.1", "--json", "--no-progress"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert (tmp_path / "cli.laz").read_bytes() == (tmp_path / "Megaplot.laz").read_bytes()
    assert [(c["class"], c["policy"], c["kept"]) for c in got["classes"]["classes"]] == [
        (1, "ratio 0.1", int((cls_out == 1).sum())), (2, "whole", int((cls_in == 2).sum()))]


@pytest.mark.parametrize("args, message", [
    (["--keep-class", "2,x"], "--keep-class: 'x' is not a class code (an integer 0..255)"),
    (["--keep-class", "256"], "--keep-class: class code 256 is out of 0..255"),
    (["--keep-class=-1"], "--keep-class: class code -1 is out of 0..255"),
    (["--class-ratio", "5:0.1"], "--class-ratio: '5:0.1' is not CODE=RATIO (e.g. 5=0.1)"),
    (["--class-ratio", "5=1.5"], "--class-ratio: the ratio of class 5 must be a number in (0, 1], got '1.5'"),
    (["--class-ratio", "5=0"], "--class-ratio: the ratio of class 5 must be a number in (0, 1], got '0'"),
    (["--class-ratio", "300=0.5"], "--class-ratio: class code 300 is out of 0..255"),
    (["--keep-class", "5", "--class-ratio", "5=0.5"],
     "class 5 is in --keep-class and has a ratio below 1 in --class-ratio: give it in one of them"),
    (["--keep-class", "2", "--rule", "iterative"],
     "--keep-class is an option of rule 'eliminate' only, not of rule 'iterative'"),
    (["--class-ratio", "2=0.5", "--rule", "target"],
     "--class-ratio is an option of rule 'eliminate' only, not of rule 'target'"),
])
def test_bad_policies_exit_2(tmp_path, capsys, args, message):
    capsys.readouterr()
    rc = main(["simplify", str(shared_file("simple.laz")), str(tmp_path / "o.laz"), "--ratio", "0.5", *args])
    assert rc == 2
    assert capsys.readouterr().err == f"cloudsieve simplify: error: {message}\n"
    assert list(tmp_path.iterdir()) == []


def test_input_without_classification_exit_2(tmp_path, capsys):
    src = shared_file("bun_zipper.ply")
    capsys.readouterr()
    rc = main(["simplify", str(src), str(tmp_path / "o.ply"), "--ratio", "0.5", "--keep-class", "2"])
    assert rc == 2
    assert capsys.readouterr().err == (f"cloudsieve simplify: error: {src}: no classification attribute, which "
                                       "keep_class and class_ratio need (LAS/LAZ/COPC have one)\n")
    assert list(tmp_path.iterdir()) == []


# sha256 of the kept records of the default run (no policy) of autzen_trim.laz at 0.3 over 6 cells, as written
# before the class policies existed
DEFAULT_RECORDS = "809fa222e2b27bc4"


def test_default_run_unchanged(tmp_path):
    src = shared_file("autzen_trim.laz")
    summary = cloudsieve.simplify(src, tmp_path / "d.laz", ratio=0.3, cell_size=20_000)
    assert summary.classes is None and "classes" not in summary.to_dict()
    digest = hashlib.sha256(records(tmp_path / "d.laz")[0].tobytes()).hexdigest()[:16]
    assert digest == DEFAULT_RECORDS


def test_killed_then_resumed_gives_the_same_bytes(tmp_path):
    """A run with policies killed in its 4th elimination task resumes from its store: only the missing cells run."""
    src = shared_file("autzen_trim.laz")
    ref = tmp_path / "ref.laz"
    cloudsieve.simplify(src, ref, ratio=0.3, keep_class="2", class_ratio="1=0.2", cell_size=20_000)
    args = ["simplify", str(src), str(tmp_path / "out.laz"), "--keep-class", "2", "--class-ratio", "1=0.2",
            "--ratio", "0.3", "--cell-size", "20000", "--store", str(tmp_path / "w.zarr"), "--scheduler", "threads",
            "--workers", "1", "--no-progress"]
    summary = kill_then_resume(args, tmp_path / "w.zarr", tmp_path / "paused")
    assert (summary["cells_reused"], summary["cells_computed"]) == (3, 3)
    assert (tmp_path / "out.laz").read_bytes() == ref.read_bytes()
