"""Start-up: the first run into an empty numba cache, the warm-up, and small files warm; prints Markdown tables.

    .venv/bin/python benchmarks/startup.py               # autzen_trim.laz and simple.las, 3 warm runs each
    .venv/bin/python benchmarks/startup.py --repeat 5 --skip cold

Every run is a fresh process (``python -m cloudsieve ...`` or a Python child),
timed whole by this driver, as a user's shell would time it:

1. **cold**: ``cloudsieve simplify FILE OUT --ratio 0.5`` of the first file
   with ``NUMBA_CACHE_DIR`` an empty folder (a fresh install, a new CI runner
   or container); then ``cloudsieve warmup --targets common,partition,eliminate``
   into another empty folder (the default rule's kernels) and the first
   ``simplify`` after it; then the whole ``cloudsieve warmup`` (what
   ``setup.sh`` runs) into a third;
2. **warm**: per file, after one untimed run, ``--repeat`` runs of
   ``cloudsieve simplify FILE OUT --ratio 0.5`` alternating with what an
   Open3D user runs on the same file: laspy reads it, Open3D's
   ``voxel_down_sample`` at the voxel size that keeps about as many points
   (found by bisection, untimed), laspy writes the LAZ; and, where
   CloudCompare is installed (Debian's ``cloudcompare``; its LAS plugin is
   not built there), what a CloudCompare user runs: ``CloudCompare -SILENT``
   reads the file's x, y, z as a binary PLY (written beforehand, untimed),
   subsamples with ``-SS SPATIAL`` at the step that keeps about as many
   points (bisection, untimed) and writes a binary PLY, beside
   ``cloudsieve simplify`` of the same PLY to a PLY (every run timed whole).
   Then the CPU seconds of each tool's fastest run (user + system, from
   ``getrusage`` of the children): on 2 cores, half of them is the least
   wall time that run could take.

The load average is printed beside each row: the machine's speed varies, so
compare rows of one run.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from engine import open3d_same_count, size_same_count  # benchmarks/engine.py, beside this script

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "data"
PY = sys.executable
#: CloudCompare's command-line binary (Debian's ``cloudcompare``), None when not installed; run without a display
CLOUDCOMPARE = shutil.which("CloudCompare")
CC_ENV = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}

# engine.py's open3d_end_to_end as a script: the user's process imports laspy, numpy and open3d only, and
# its imports are timed with it (importing engine.py would add cloudsieve's to Open3D's side)
OPEN3D = r"""
import sys
import laspy, numpy as np, open3d as o3d
src, dst, voxel = sys.argv[1], sys.argv[2], float(sys.argv[3])
las = laspy.read(src)
origin = np.array([las.header.x_min, las.header.y_min, las.header.z_min])
pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[las.x, las.y, las.z] - origin))
out = np.asarray(pcd.voxel_down_sample(voxel).points) + origin
header = laspy.LasHeader(point_format=0, version="1.2")
header.scales, header.offsets = las.header.scales, las.header.offsets
w = laspy.LasData(header)
w.x, w.y, w.z = out[:, 0], out[:, 1], out[:, 2]
w.write(dst)
print(len(out))
"""


def load() -> str:
    return "{:.1f}".format(os.getloadavg()[0])


class Run(NamedTuple):
    wall: float  # seconds, timed whole by this driver
    out: str  # its stdout
    cpu: float  # user + system seconds of the process and its children


def timed(cmd: list[str], env: dict | None = None) -> Run:
    """Run *cmd* (a fresh process); raises when it fails."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return Run(wall, proc.stdout, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)


def simplify_cmd(src: Path, dst: Path) -> list[str]:
    return [PY, "-m", "cloudsieve", "simplify", str(src), str(dst), "--ratio", "0.5", "--overwrite", "--no-progress"]


def cold(src: Path, work: Path) -> None:
    print(f"\nFirst runs, `{src.name}`, `--ratio 0.5`, an empty `NUMBA_CACHE_DIR` each:\n")
    print("| run | wall (s) | load before / after |")
    print("|---|---:|---|")
    warmup = [PY, "-m", "cloudsieve", "warmup"]
    caches = [  # the runs into each empty cache, in turn
        [("`simplify`, nothing compiled", simplify_cmd(src, work / "cold.laz"))],
        [("`warmup --targets common,partition,eliminate`", [*warmup, "--targets", "common,partition,eliminate"]),
         ("`simplify`, first run after that warm-up", simplify_cmd(src, work / "cold.laz"))],
        [("`warmup`, every target (what setup.sh runs)", warmup)],
    ]
    env = {**os.environ}
    for runs in caches:
        with tempfile.TemporaryDirectory(dir=work) as cache:
            env["NUMBA_CACHE_DIR"] = cache
            for label, cmd in runs:
                l0 = load()
                wall = timed(cmd, env).wall
                print(f"| {label} | {wall:.1f} | {l0} / {load()} |")


def cloudcompare_cmd(src: Path, step: float, dst: Path | None = None) -> list[str]:
    """CloudCompare's command line: SRC (PLY) subsampled by ``-SS SPATIAL`` at *step*, saved as a binary PLY to
    *dst* (None: not saved). Coordinates this large are shifted to the origin (``-GLOBAL_SHIFT AUTO``), as its
    dialog proposes."""
    cmd = [CLOUDCOMPARE, "-SILENT", "-AUTO_SAVE", "OFF", "-O", "-GLOBAL_SHIFT", "AUTO", str(src), "-SS", "SPATIAL",
           repr(step)]
    if dst is not None:
        cmd += ["-C_EXPORT_FMT", "PLY", "-PLY_EXPORT_FMT", "BINARY_LE", "-SAVE_CLOUDS", "FILE", str(dst)]
    return cmd


def cloudcompare_kept(out: str) -> int:
    """The points CloudCompare's log says ``-SS`` kept."""
    return int(re.search(r"Result: (\d+) points", out).group(1))


def spatial_same_count(ply: Path, count: int, voxel: float) -> float:
    """The ``-SS SPATIAL`` step at which CloudCompare keeps about *count* points of *ply* (bisection from
    Open3D's voxel size *voxel*: within 1% or the closest of 12 runs)."""
    return size_same_count(lambda step: cloudcompare_kept(timed(cloudcompare_cmd(ply, step), CC_ENV).out), count,
                           voxel / 8, voxel * 2, 0.01, 12)


def write_ply(src: Path, dst: Path) -> None:
    """x, y, z of *src* as a binary PLY (CloudCompare's input: its Debian build reads no LAS), streamed chunk by
    chunk through cloudsieve's own reader and writer."""
    import numpy as np

    from cloudsieve.io import open_reader, open_writer

    xyz = {"xyz": (np.dtype(np.float64), (3,))}
    with open_reader(src) as reader, open_writer(dst, header={}, dtypes=xyz, overwrite=True) as writer:
        for chunk in reader.chunks():
            writer.write({"xyz": chunk.arrays["xyz"]})


#: the tools of the warm table, as its CPU lines name them
NAMES = {"ours": "cloudsieve", "open3d": "laspy + Open3D", "ours_ply": "cloudsieve PLY to PLY",
         "cloudcompare": "CloudCompare"}


def times(ts: list[float]) -> str:
    return ", ".join(f"{t:.2f}" for t in ts)


def warm(files: list[Path], work: Path, repeat: int) -> None:
    import laspy

    cc = CLOUDCOMPARE is not None
    cpu = []
    print(f"\nWarm runs, `--ratio 0.5`, alternating, {repeat} each (fresh processes):\n")
    print("| file | points | `cloudsieve simplify` (s) | laspy + Open3D voxel + laspy (s) | ratio | "
          "`cloudsieve simplify`, PLY to PLY (s) | CloudCompare `-SS SPATIAL`, PLY to PLY (s) | ratio | load |")
    print("|---|---:|---|---|---:|---|---|---:|---|")
    for src in files:
        with laspy.open(str(src)) as reader:
            n = int(reader.header.point_count)
        voxel = open3d_same_count(src, n // 2)[2]  # the voxel size keeping about half (bisection, untimed)
        timed(simplify_cmd(src, work / "warm.laz"))  # fills the cache if this file needs a kernel not yet in it
        ply = work / (src.stem + ".ply")
        if cc:
            write_ply(src, ply)
            step = spatial_same_count(ply, n // 2, voxel)
            timed(simplify_cmd(ply, work / "warm.ply"))
        runs: dict[str, list[Run]] = {"ours": [], "open3d": [], "ours_ply": [], "cloudcompare": []}
        l0 = load()
        for _ in range(repeat):
            runs["ours"].append(timed(simplify_cmd(src, work / "warm.laz")))
            runs["open3d"].append(timed([PY, "-c", OPEN3D, str(src), str(work / "o3d.laz"), repr(voxel)]))
            if cc:
                runs["ours_ply"].append(timed(simplify_cmd(ply, work / "warm.ply")))
                runs["cloudcompare"].append(timed(cloudcompare_cmd(ply, step, work / "cc.ply"), CC_ENV))
        wall = {k: [r.wall for r in v] for k, v in runs.items()}
        if cc:
            side = (f"{times(wall['ours_ply'])} | {times(wall['cloudcompare'])} "
                    f"({cloudcompare_kept(runs['cloudcompare'][-1].out):,} points, step {step:.4g}) | "
                    f"{min(wall['ours_ply']) / min(wall['cloudcompare']):.1f}x")
        else:
            side = "| CloudCompare not installed (`apt-get install cloudcompare`) |"
        print(f"| {src.name} | {n:,} | {times(wall['ours'])} | {times(wall['open3d'])} | "
              f"{min(wall['ours']) / min(wall['open3d']):.1f}x | {side} | {l0}-{load()} |")
        fastest = {k: min(v, key=lambda r: r.wall) for k, v in runs.items() if v}
        cpu.append(f"{src.name}: " + ", ".join(f"{NAMES[k]} {r.cpu:.2f}" for k, r in fastest.items()))
    print("\nCPU seconds (user + system, the process and its children) of each tool's fastest run:\n")
    for line in cpu:
        print(f"- {line}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--files", default=f"{DATA / 'autzen_trim.laz'},{DATA / 'simple.las'}",
                   help="comma-separated LAS/LAZ files (default: autzen_trim.laz and simple.las of ../shared/data); "
                        "the first one is the cold runs'")
    p.add_argument("--repeat", type=int, default=3, help="warm runs of each tool per file (default 3)")
    p.add_argument("--skip", default="", help="comma-separated: cold, warm")
    p.add_argument("--workdir", default="/tmp/cloudsieve-bench-startup", help="folder for the outputs and caches")
    args = p.parse_args(argv)
    files = [Path(f) for f in args.files.split(",") if f]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        p.error(f"no such file: {', '.join(missing)}")
    skip = {s for s in args.skip.split(",") if s}
    work = Path(args.workdir)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    print(f"# cloudsieve start-up, {os.cpu_count()} cores, load {load()}")
    if "cold" not in skip:
        cold(files[0], work)
    if "warm" not in skip:
        warm(files, work, args.repeat)
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
