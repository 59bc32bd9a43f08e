"""Make a large, realistic LAZ scan of N points, streaming (never N points in memory).

    .venv/bin/python benchmarks/make_scan.py 20000000 /tmp/scan20m.laz [--seed 0]

The real aerial survey ``autzen_trim.laz`` (110,000 points, ../shared/data)
is tiled on a grid, each tile mirrored/jittered differently (xyz noise of a
few centimetres, intensity noise, shifted GPS time, a small random height
offset), so the result keeps real point density, classes, returns, colours
and structure. Without that file a synthetic scene is generated instead:
terrain (class 2), buildings (class 6: walls and roofs) and vegetation (class
5) with intensity, returns, GPS time and RGB. Output: LAS 1.2 point format 3
LAZ, written chunk by chunk; the same seed gives the same file.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import math
import sys
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
AUTZEN = ROOT.parent / "shared" / "data" / "autzen_trim.laz"
TILE = 100_000  # points per synthetic tile


def _autzen_tile() -> tuple[laspy.LasHeader, laspy.ScaleAwarePointRecord] | None:
    if not AUTZEN.is_file():
        return None
    las = laspy.read(AUTZEN)  # 110k points: the base tile, small by design
    return las.header, las.points


def _synthetic_tile(rng: np.random.Generator, header: laspy.LasHeader, n: int, size: float = 500.0):
    """Terrain + buildings + vegetation on a size x size m tile, n points."""
    rec = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    kind = rng.choice(3, size=n, p=[0.6, 0.2, 0.2])  # 0 ground, 1 building, 2 vegetation
    x = rng.uniform(0, size, n)
    y = rng.uniform(0, size, n)
    ground = 120 + 8 * np.sin(x / 90.0) * np.cos(y / 70.0) + 0.05 * rng.standard_normal(n)
    z = ground.copy()
    # buildings: 12 boxes per tile
    centres = rng.uniform(40, size - 40, (12, 2))
    half = rng.uniform(8, 25, (12, 2))
    height = rng.uniform(5, 30, 12)
    b = kind == 1
    which = rng.integers(0, 12, int(b.sum()))
    u = rng.uniform(-1, 1, (len(which), 2))
    bx = centres[which, 0] + u[:, 0] * half[which, 0]
    by = centres[which, 1] + u[:, 1] * half[which, 1]
    wall = rng.random(len(which)) < 0.3
    side = rng.integers(0, 2, len(which))
    bx = np.where(wall & (side == 0), centres[which, 0] + np.sign(u[:, 0]) * half[which, 0], bx)
    by = np.where(wall & (side == 1), centres[which, 1] + np.sign(u[:, 1]) * half[which, 1], by)
    x[b], y[b] = bx, by
    base = 120 + 8 * np.sin(bx / 90.0) * np.cos(by / 70.0)
    z[b] = np.where(wall, base + rng.uniform(0, 1, len(which)) * height[which], base + height[which])
    # vegetation: crowns around 60 trees
    v = kind == 2
    trees = rng.uniform(0, size, (60, 2))
    th = rng.uniform(4, 20, 60)
    which = rng.integers(0, 60, int(v.sum()))
    r = rng.uniform(0, 1, len(which)) ** 0.5 * th[which] * 0.3
    a = rng.uniform(0, 2 * np.pi, len(which))
    x[v] = trees[which, 0] + r * np.cos(a)
    y[v] = trees[which, 1] + r * np.sin(a)
    z[v] = 120 + 8 * np.sin(x[v] / 90.0) * np.cos(y[v] / 70.0) + th[which] * rng.uniform(0.3, 1.0, len(which))
    rec.x, rec.y, rec.z = x, y, z
    rec.classification = np.choose(kind, [2, 6, 5]).astype(np.uint8)
    nret = np.where(kind == 2, rng.integers(1, 4, n), 1)
    rec.number_of_returns = nret
    rec.return_number = np.minimum(rng.integers(1, 4, n), nret)
    rec.intensity = np.clip(rng.normal(np.choose(kind, [300, 700, 150]), 60), 0, 65535).astype(np.uint16)
    rec.gps_time = np.sort(rng.uniform(0, 100, n))
    base_rgb = np.array([[120, 110, 90], [180, 60, 50], [40, 120, 40]], dtype=np.float64)[kind]
    rgb = np.clip(base_rgb + rng.normal(0, 15, (n, 3)), 0, 255) * 257
    rec.red, rec.green, rec.blue = (rgb[:, i].astype(np.uint16) for i in range(3))
    rec.scan_angle_rank = rng.integers(-20, 21, n).astype(np.int8)
    rec.point_source_id = np.ones(n, dtype=np.uint16)
    return rec


def make_scan(n: int, out: str, seed: int = 0, chunk: int = 1_000_000, files: int = 1) -> int:
    """Write *n* points to *out* (LAZ); returns the number written.

    With *files* > 1, *out* is a folder that gets that many LAZ files
    ``tile_0000.laz``, ... of about n / files points each: the same scene,
    cut where the points fall in the sequence (each file a band of the grid),
    as a tiled delivery of one survey.
    """
    base = _autzen_tile()
    if base is not None:
        src_header, src = base
        header = laspy.LasHeader(version=src_header.version, point_format=src_header.point_format)
        header.vlrs = [v for v in src_header.vlrs if type(v).__name__ != "LasZipVlr"]
        header.scales = src_header.scales
        header.offsets = np.floor(src_header.mins)
        header.system_identifier = "cloudsieve make_scan"
        mins, maxs = src_header.mins, src_header.maxs
        tile_n = len(src)
        width, height = maxs[0] - mins[0], maxs[1] - mins[1]
        gps_span = float(np.ptp(src.gps_time)) + 1.0
    else:
        header = laspy.LasHeader(version="1.2", point_format=3)
        header.scales = np.array([0.01, 0.01, 0.01])
        header.offsets = np.zeros(3)
        header.system_identifier = "cloudsieve make_scan (synthetic)"
        tile_n = TILE
        width = height = 500.0
        mins = np.zeros(3)
        gps_span = 100.0
    header.creation_date = datetime.date(2026, 1, 1)  # fixed: same seed, same bytes
    n_tiles = math.ceil(n / tile_n)
    cols = max(1, math.ceil(math.sqrt(n_tiles)))
    written = 0
    pending: list[laspy.ScaleAwarePointRecord] = []
    pending_n = 0
    per_file = math.ceil(n / files)
    if files > 1:
        Path(out).mkdir(parents=True, exist_ok=True)
        chunk = min(chunk, per_file)

    def open_file(k: int):
        path = Path(out) / f"tile_{k:04d}.laz" if files > 1 else out
        return laspy.open(path, mode="w", header=header, do_compress=True)

    writer = open_file(0)
    with contextlib.ExitStack() as stack:
        stack.callback(lambda: writer.close())
        for t in range(n_tiles):
            rng = np.random.default_rng([seed, t])
            take = min(tile_n, n - written - pending_n)
            row, col = divmod(t, cols)
            if base is not None:
                x = src.x.copy()
                y = src.y.copy()
                # mirror every other tile so that tiles meet edge to edge
                if col % 2:
                    x = mins[0] + maxs[0] - x
                if row % 2:
                    y = mins[1] + maxs[1] - y
                rec = laspy.ScaleAwarePointRecord(src.array.copy(), src.point_format, header.scales, header.offsets)
                m = len(rec)
                rec.x = x + col * width + rng.normal(0, 0.03, m)
                rec.y = y + row * height + rng.normal(0, 0.03, m)
                rec.z = np.asarray(src.z) + rng.normal(0, 0.02, m) + rng.normal(0, 0.5)
                rec.intensity = np.clip(rec.intensity.astype(np.int64) + rng.integers(-8, 9, m), 0, 65535).astype(
                    np.uint16
                )
                rec.gps_time = np.asarray(src.gps_time) + t * gps_span
            else:
                rec = _synthetic_tile(rng, header, tile_n)
                rec.x = np.asarray(rec.x) + col * width
                rec.y = np.asarray(rec.y) + row * height
                rec.gps_time = np.asarray(rec.gps_time) + t * gps_span
            if take < len(rec):
                rec = rec[:take]
            pending.append(rec)
            pending_n += len(rec)
            while pending_n >= chunk or (pending_n and written + pending_n >= n):
                arr = np.concatenate([p.array for p in pending])
                room = per_file - written % per_file  # points the current file still takes
                head, rest = arr[:room], arr[room:]
                writer.write_points(laspy.ScaleAwarePointRecord(head, header.point_format, header.scales,
                                                                header.offsets))
                written += len(head)
                pending = [laspy.ScaleAwarePointRecord(rest, header.point_format, header.scales, header.offsets)]
                pending_n = len(rest)
                if not pending_n:
                    pending = []
                if written % per_file == 0 and written < n:
                    writer.close()
                    writer = open_file(written // per_file)
            if written >= n:
                break
    return written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("n", type=float, help="number of points (1e6 notation accepted)")
    p.add_argument("out", help="output .laz")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--chunk-size", type=int, default=1_000_000)
    p.add_argument("--files", type=int, default=1, help="write that many tiles into the folder OUT instead of one file")
    args = p.parse_args(argv)
    n = int(args.n)
    written = make_scan(n, args.out, seed=args.seed, chunk=args.chunk_size, files=args.files)
    src = "autzen_trim.laz tiles" if AUTZEN.is_file() else "synthetic scene"
    print(f"wrote {written} points ({src}, seed {args.seed}) to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
