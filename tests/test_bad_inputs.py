"""Every failure the README's "Errors and recovery" section promises, as a table a user can read.

Each row is one command line run through ``cloudsieve.cli.main``: it must
exit with code 2, print ``cloudsieve COMMAND: error: ...`` with the message
in the last column on stderr, and create nothing (the output folder stays
empty, the inputs are untouched). ``{in}`` is a folder of bad inputs made
from the real scans in ../shared/data (see :func:`inputs`), ``{out}`` an
empty folder for outputs, ``{data}`` ../shared/data itself.

Below the table, a Hypothesis test mangles real LAS, LAZ and PLY files
(truncated, bytes flipped in header and body, wrong point counts) and asserts
that ``read_cloud``, ``ingest`` and ``simplify --rule threshold`` either
succeed or raise a ``CloudsieveError`` naming the file: never another
exception, never a partial output.
"""

from __future__ import annotations

import json
import shlex
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cloudsieve
from cloudsieve.cli import main
from cloudsieve.errors import CloudsieveError
from cloudsieve.io import read_cloud
from cloudsieve.store import ingest
from conftest import DATA_DIR, shared_file

WRITABLE = "las (.las), laz (.laz), copc (.copc.laz), ply (.ply), xyz (.xyz .txt .csv .pts)"

# fmt: off
CASES = [
    # id                          command line                                                      exit  message (after "cloudsieve COMMAND: error: ")
    # -- the input
    ("missing-file",              "simplify {in}/missing.laz {out}/o.laz --ratio 0.5",                            2, "{in}/missing.laz: no such file"),
    ("directory-given",           "simplify {in}/folder.las {out}/o.laz --ratio 0.5",                             2, "{in}/folder.las is a directory, not a point cloud file or point store"),
    ("unknown-extension",         "ingest {in}/scan.foo {out}/s.zarr",                                2, "{in}/scan.foo: unknown point cloud format (extension .foo)"),
    ("truncated-las",             "ingest {in}/cut.las {out}/s.zarr",                                 2, "{in}/cut.las: header says 1065 points but the file holds data for only 581 (truncated or corrupt)"),
    ("truncated-las-header",      "ingest {in}/header.las {out}/s.zarr",                              2, "{in}/header.las: not a valid LAS/LAZ file"),
    ("corrupt-las-signature",     "ingest {in}/signature.las {out}/s.zarr",                           2, "{in}/signature.las: not a valid LAS/LAZ file"),
    ("las-count-disagrees",       "ingest {in}/count.las {out}/s.zarr",                               2, "{in}/count.las: header says 1075 points but the file holds data for only 1065"),
    ("truncated-laz",             "simplify {in}/cut.laz {out}/o.laz --scheduler sync --ratio 0.5",               2, "{in}/cut.laz: cannot decode point 434 of 1065 (points 0 to 433 decode; IoError: failed to fill whole buffer); truncated or corrupt"),
    ("truncated-ply",             "ingest {in}/cut.ply {out}/s.zarr",                                 2, "{in}/cut.ply: header says 500 vertices but the file holds data for only 323 (truncated)"),
    ("not-a-ply",                 "ingest {in}/text.ply {out}/s.zarr",                                2, "{in}/text.ply: not a PLY file (first line b'hello', expected 'ply')"),
    ("ply-without-xyz",           "ingest {in}/noxyz.ply {out}/s.zarr",                               2, "{in}/noxyz.ply: PLY vertex element has no x/y/z properties (found: x, y)"),
    ("nan-coordinates",           "simplify {in}/nan.xyz {out}/o.laz --scheduler sync --ratio 0.5",               2, "{in}/nan.xyz: 2 of 300 points have NaN or infinite coordinates (first: point 5); pass --drop-invalid to drop them"),
    ("nan-coordinates-evaluate",  "evaluate {in}/nan.xyz {in}/nan.xyz --no-surface",                  2, "{in}/nan.xyz: 2 of 300 points have NaN or infinite coordinates (first: point 5); pass --drop-invalid to drop them"),
    ("empty-file",                "ingest {in}/empty.laz {out}/s.zarr",                               2, "{in}/empty.laz is empty (0 bytes)"),
    ("no-points",                 "ingest {in}/header-only.xyz {out}/s.zarr",                         2, "{in}/header-only.xyz holds no points"),
    ("store-not-found",           "export {in}/folder.las {out}/o.las",                               2, "{in}/folder.las is not a cloudsieve point store"),
    ("missing-mask-array",        "export {in}/s.zarr {out}/o.las --mask simplify/keep",              2, "{in}/s.zarr has no array 'simplify/keep'"),
    ("incompatible-clouds",       "evaluate {data}/simple.las {in}/feet.xyz --no-surface",            2, "(pass --no-strict to compare anyway)"),
    # -- the destination
    ("destination-exists",        "simplify {data}/simple.las {in}/exists.las --scheduler sync --ratio 0.5",      2, "{in}/exists.las exists; pass --overwrite to replace it"),
    ("store-exists",              "ingest {data}/simple.las {in}/s.zarr",                             2, "{in}/s.zarr exists (a folder); pass --overwrite to replace it"),
    ("destination-is-source",     "simplify {in}/exists.las {in}/exists.las --overwrite --ratio 0.5",             2, "{in}/exists.las is the source: cloudsieve never overwrites its input"),
    ("store-is-source",           "export {in}/s.zarr {in}/s.zarr --format las --overwrite",          2, "destination {in}/s.zarr is the source {in}/s.zarr: cloudsieve never overwrites its input"),
    ("folder-missing",            "simplify {data}/simple.las {out}/nowhere/o.laz --ratio 0.5",                   2, "cannot write {out}/nowhere/o.laz: folder {out}/nowhere does not exist"),
    ("folder-is-a-file",          "export {in}/s.zarr {in}/afile/o.las",                              2, "cannot write {in}/afile/o.las: {in}/afile is not a folder"),
    ("folder-not-writable",       "export {in}/s.zarr /proc/cloudsieve-test.las",                     2, "cannot write /proc/cloudsieve-test.las:"),
    ("report-folder-is-a-file",   "evaluate {data}/simple.las {data}/simple.laz --report {in}/afile/r", 2, "cannot write {in}/afile/r: {in}/afile is not a folder"),
    ("format-not-writable-e57",   "simplify {data}/simple.las {out}/o.e57 --ratio 0.5",                           2, f"{{out}}/o.e57: writing e57 files is not supported; formats that can be written: {WRITABLE}"),
    ("format-unknown",            "export {in}/s.zarr {out}/o.foo",                                   2, "{out}/o.foo: unknown point cloud format (extension .foo)"),
    ("demo-folder-not-empty",     "demo --out {in} --points 1000",                                    2, "{in} exists and is not empty"),
    # -- the options
    ("ratio-out-of-range",        "simplify {data}/simple.las {out}/o.laz --ratio 1.5",               2, "ratio must be a number in (0, 1], got 1.5"),
    ("count-zero",                "simplify {data}/simple.las {out}/o.laz --count 0",                 2, "count must be an integer >= 1, got 0"),
    ("ratio-and-count",           "simplify {data}/simple.las {out}/o.laz --ratio 0.5 --count 10",    2, "give ratio or count, not both (got ratio=0.5, count=10)"),
    ("target-without-ratio",      "simplify {data}/simple.las {out}/o.laz --rule target",             2, "rule 'target' needs a ratio or a count"),
    ("cluster-size-too-small",    "simplify {data}/simple.las {out}/o.laz --cluster-size 5 --ratio 0.5",          2, "--cluster-size 5 is too small: a cluster needs at least k_min+2=6 points"),
    ("unknown-scheduler",         "simplify {data}/simple.las {out}/o.laz --scheduler fast",          2, "unknown scheduler 'fast': use sync, threads, processes or a tcp://host:port address"),
    ("unreachable-scheduler",     "simplify {data}/simple.las {out}/o.laz --scheduler tcp://127.0.0.1:1 --ratio 0.5", 2, "cannot reach the dask scheduler at tcp://127.0.0.1:1: Connection refused (connect timeout 5 s)"),
    ("compare-unknown-method",    "compare {data}/simple.las --methods km,grid",                      2, "unknown method(s) ['grid']; choose among km, fcm, random, voxel, poisson, fps"),
    # -- pipelines
    ("pipeline-missing",          "run {in}/nope.json",                                               2, "{in}/nope.json: no such pipeline file"),
    ("pipeline-not-json",         "run {in}/not-json.json",                                           2, "{in}/not-json.json: not valid JSON: Expecting value at line 1, column 15"),
    ("pipeline-no-stages",        "run {in}/no-stages.json",                                          2, "{in}/no-stages.json: the pipeline has no stages"),
    ("pipeline-unknown-stage",    "run {in}/unknown-stage.json",                                      2, "{in}/unknown-stage.json: stage 2 (filters.smooth): unknown stage type; known after the reader: writers.las, writers.ply, writers.text, filters.entropy, evaluate, compare"),
    ("pipeline-unknown-key",      "run {in}/typo.json --check",                                       2, "{in}/typo.json: stage 1 (readers.las): unknown option(s) ['filenme']; accepted: ['drop_invalid', 'filename', 'merge']"),
    ("pipeline-bad-value",        "run {in}/bad-value.json",                                          2, "{in}/bad-value.json: stage 2 (filters.entropy): ratio must be a number in (0, 1], got 2"),
    ("pipeline-unset-variable",   "run {in}/unset-variable.json --check",                             2, "{in}/unset-variable.json: stage 1 (readers.ply): filename '$CLOUDSIEVE_TEST_UNSET/bun.ply' uses the environment variable CLOUDSIEVE_TEST_UNSET, which is not set"),
    ("pipeline-missing-input",    "run {in}/missing-input.json --check",                              2, "{in}/missing-input.json: stage 1 (readers.las): {in}/missing.laz: no such file"),
    ("pipeline-destination-exists", "run {in}/exists.json",                                           2, '{in}/exists.las exists; pass "overwrite": true in the writers.las stage (or --set writers.las.overwrite=true) to replace it'),
]
# fmt: on


def write_ply(path, xyz, properties=("x", "y", "z")):
    """A binary little-endian PLY of *xyz* (float), with the given vertex properties."""
    body = np.empty(len(xyz), dtype=[(p, "<f4") for p in properties])
    for i, p in enumerate(properties):
        body[p] = xyz[:, i]
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(xyz)
    header += "".join(f"property float {p}\n" for p in properties) + "end_header\n"
    path.write_bytes(header.encode() + body.tobytes())


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The folder of bad inputs ({in}), each made from a real scan."""
    d = tmp_path_factory.mktemp("inputs")  # shared_file skips where ../shared/data is absent
    las, laz = shared_file("simple.las").read_bytes(), shared_file("simple.laz").read_bytes()
    bunny, _ = read_cloud(shared_file("bun_zipper.ply"))
    (d / "folder.las").mkdir()
    (d / "scan.foo").write_text("1 2 3\n")
    (d / "cut.las").write_bytes(las[:20_000])
    (d / "header.las").write_bytes(las[:100])
    (d / "signature.las").write_bytes(b"XXXX" + las[4:])
    count = bytearray(las)
    count[107:111] = (1075).to_bytes(4, "little")  # the LAS 1.2 point count
    (d / "count.las").write_bytes(bytes(count))
    (d / "cut.laz").write_bytes(laz[:8000])
    write_ply(d / "full.ply", bunny[:500])
    (d / "cut.ply").write_bytes((d / "full.ply").read_bytes()[:4000])
    (d / "full.ply").unlink()
    (d / "text.ply").write_text("hello\n")
    write_ply(d / "noxyz.ply", bunny[:10, :2], properties=("x", "y"))
    xyz = np.random.default_rng(0).random((300, 3))
    xyz[5, 0], xyz[77, 1] = np.nan, np.inf
    np.savetxt(d / "nan.xyz", xyz, fmt="%.6f")
    (d / "empty.laz").write_bytes(b"")
    (d / "header-only.xyz").write_text("x y z\n")
    (d / "exists.las").write_bytes(las)
    (d / "afile").write_text("a file, not a folder")
    ingest(shared_file("simple.las"), d / "s.zarr")
    simple, _ = read_cloud(shared_file("simple.las"))
    np.savetxt(d / "feet.xyz", simple[::2] * 1000.0, fmt="%.3f")
    reader = {"type": "readers.las", "filename": str(shared_file("simple.las"))}
    entropy, writer = {"type": "filters.entropy", "ratio": 0.5}, {"type": "writers.las", "filename": str(d / "o.las")}
    pipelines = {
        "not-json": '{"pipeline": [,]}',
        "no-stages": {"pipeline": []},
        "unknown-stage": {"pipeline": [reader, {"type": "filters.smooth"}]},
        "typo": {"pipeline": [{"type": "readers.las", "filenme": "scan.las"}, entropy, writer]},
        "bad-value": {"pipeline": [reader, {"type": "filters.entropy", "rule": "target", "ratio": 2}, writer]},
        "unset-variable": {"pipeline": [{"type": "readers.ply", "filename": "$CLOUDSIEVE_TEST_UNSET/bun.ply"},
                                        {"type": "compare", "ratio": 0.5}]},
        "missing-input": {"pipeline": [{"type": "readers.las", "filename": str(d / "missing.laz")}, entropy, writer]},
        "exists": {"scheduler": "sync",
                   "pipeline": [reader, entropy, {"type": "writers.las", "filename": str(d / "exists.las")}]},
    }
    for name, doc in pipelines.items():
        (d / f"{name}.json").write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return d


def snapshot(folder):
    """Every path under *folder* with its size and mtime: what "nothing created, nothing touched" compares."""
    return sorted((p.relative_to(folder).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                  for p in folder.rglob("*"))


@pytest.mark.parametrize("case, line, code, message", CASES, ids=[c[0] for c in CASES])
def test_bad_input(case, line, code, message, inputs, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("CLOUDSIEVE_TEST_UNSET", raising=False)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    places = {"in": inputs, "out": out, "data": DATA_DIR}
    argv = [arg.format(**places) for arg in shlex.split(line)]
    before = snapshot(inputs)
    capsys.readouterr()
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == code, err
    assert err.startswith(f"cloudsieve {argv[0]}: error: "), err
    assert message.format(**places) in err, err
    assert err.count("\n") == 1, err  # one line
    assert snapshot(out) == [] and listing(tmp_path) == ["out"]
    assert snapshot(inputs) == before


def listing(folder):
    return sorted(p.name for p in folder.iterdir())


# ------------------------------------------------------------------ mangled real files (Hypothesis)


def _las_count_offsets(data: bytes) -> list[tuple[int, int]]:
    """(offset, width) of the point-count fields of a LAS header: legacy u32, and u64 for LAS 1.4."""
    fields = [(107, 4)]
    if data[25] >= 4:
        fields.append((247, 8))
    return fields


def _ply_with_count(data: bytes, count: int) -> bytes:
    head, sep, body = data.partition(b"end_header\n")
    lines = head.split(b"\n")
    lines = [b"element vertex %d" % count if line.startswith(b"element vertex") else line for line in lines]
    return b"\n".join(lines) + sep + body


def _small_ply_sources(folder) -> dict[str, bytes]:
    bunny, attrs = read_cloud(shared_file("bun_zipper.ply"))
    write_ply(folder / "b.ply", bunny[:400])
    binary = (folder / "b.ply").read_bytes()
    rows = "\n".join(" ".join(f"{v:.6f}" for v in p) for p in bunny[:400])
    ascii_ = ("ply\nformat ascii 1.0\ncomment from bun_zipper.ply\nelement vertex 400\nproperty float x\n"
              "property float y\nproperty float z\nend_header\n" + rows + "\n").encode()
    return {"binary.ply": binary, "ascii.ply": ascii_}


def _header_end(data: bytes, kind: str) -> int:
    return int.from_bytes(data[94:96], "little") if kind == "las" else data.index(b"end_header") + 11


@st.composite
def manglings(draw, data: bytes, kind: str):
    """How to mangle *data*: ("truncate", at), ("flip-header" / "flip-body", [(offset, xor), ...]) or ("count", n)."""
    how = draw(st.sampled_from(["truncate", "flip-header", "flip-body", "count"]))
    if how == "truncate":
        return how, draw(st.integers(0, len(data) - 1))
    if how in ("flip-header", "flip-body"):
        end = _header_end(data, kind)
        lo, hi = (0, end) if how == "flip-header" else (end, len(data))
        return how, draw(st.lists(st.tuples(st.integers(lo, hi - 1), st.integers(1, 255)), min_size=1, max_size=8))
    return how, draw(st.one_of(st.integers(0, 3000), st.integers(0, 2**32 - 1)))


def mangle(data: bytes, kind: str, how: str, arg) -> bytes:
    """*data* truncated, with bytes flipped, or with a wrong point count in its header."""
    if how == "truncate":
        return data[:arg]
    out = bytearray(data)
    if how.startswith("flip"):
        for offset, xor in arg:
            out[offset] ^= xor
        return bytes(out)
    if kind == "ply":
        return _ply_with_count(data, arg)
    for offset, width in _las_count_offsets(data):
        out[offset : offset + width] = min(arg, 2 ** (8 * width) - 1).to_bytes(width, "little")
    return bytes(out)


def _check_mangled(folder, name: str, data: bytes) -> None:
    """read_cloud, ingest and simplify --rule threshold: success, or a CloudsieveError naming the file; no output left."""
    for p in folder.iterdir():
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    src = folder / name
    src.write_bytes(data)

    def attempt(call):
        try:
            call()
        except CloudsieveError as exc:
            assert str(src) in str(exc), f"{type(exc).__name__}: {exc}"
            assert sorted(p.name for p in folder.iterdir()) == [name], f"left behind after: {exc}"

    attempt(lambda: read_cloud(src))
    attempt(lambda: ingest(src, folder / "s.zarr", chunk_size=300))
    for p in folder.glob("*.zarr"):
        shutil.rmtree(p)
    attempt(lambda: cloudsieve.simplify(src, folder / "out.las", rule="threshold", scheduler="sync", cell_size=2000))


MANGLE_SETTINGS = settings(max_examples=40, deadline=None, derandomize=True,
                           suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                                  HealthCheck.data_too_large])


@pytest.mark.parametrize("name", ["simple.las", "simple.laz"])
def test_mangled_las_laz(name, tmp_path):
    data = shared_file(name).read_bytes()

    @MANGLE_SETTINGS
    @given(manglings(data, "las"))
    def check(how):
        _check_mangled(tmp_path, "m" + name[-4:], mangle(data, "las", *how))

    check()


def test_mangled_ply(tmp_path):
    sources = _small_ply_sources(tmp_path)  # binary and ASCII
    work = tmp_path / "work"
    work.mkdir()

    @MANGLE_SETTINGS
    @given(st.sampled_from(sorted(sources)).flatmap(lambda n: manglings(sources[n], "ply").map(lambda how: (n, how))))
    def check(case):
        name, how = case
        _check_mangled(work, "m.ply", mangle(sources[name], "ply", *how))

    check()


def _patched(name: str, patches: dict[int, bytes]) -> bytes:
    data = bytearray(shared_file(name).read_bytes())
    for offset, value in patches.items():
        data[offset : offset + len(value)] = value
    return bytes(data)


def test_mangled_cases_hypothesis_found(tmp_path, capsys):
    """Files Hypothesis found that raised other exceptions (or took gigabytes) before: each now fails cleanly or works."""
    data = shared_file("1_4_w_evlr.laz").read_bytes()
    evlr = int.from_bytes(data[235:243], "little")  # start of the first EVLR
    cases = {
        # LAS version 0.2 (a flipped minor version byte): laspy read it, then could not write it
        "version.las": (_patched("simple.las", {24: b"\x00"}), "the header says LAS version 0.2, not 1.0 to 1.4"),
        # an EVLR length of ~2**62: laspy allocated it (MemoryError, or the memory taken)
        "length.laz": (_patched("1_4_w_evlr.laz", {evlr + 20: (2**62).to_bytes(8, "little")}),
                       "the header lists 1 extended VLRs but only 0 fit in the file"),
        # the first EVLR beyond 2**63: a seek raised OSError
        "start.laz": (_patched("1_4_w_evlr.laz", {235: (2**64 - 5).to_bytes(8, "little")}),
                      "the header lists 1 extended VLRs but only 0 fit in the file"),
        # a byte of an EVLR description that is not ASCII: the writer raised UnicodeEncodeError
        "description.laz": (_patched("1_4_w_evlr.laz", {evlr + 28 + 3: bytes([data[evlr + 28 + 3] ^ 0xC0])}), None),
    }
    for name, (content, message) in cases.items():
        folder = tmp_path / name.split(".")[0]
        folder.mkdir()
        _check_mangled(folder, name, content)
        out = folder / "out.laz"
        rc = main(["simplify", str(folder / name), str(out), "--rule", "threshold", "--scheduler", "sync",
                   "--no-progress"])
        err = capsys.readouterr().err
        if message is None:
            assert rc == 0 and out.exists(), err
        else:
            assert rc == 2 and message in err and not out.exists(), err
