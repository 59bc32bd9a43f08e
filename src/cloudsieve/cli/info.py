"""``cloudsieve info PATH``: format, count, bounds, attributes and CRS of a file or store, or of the files of
one cloud (a glob, a directory, a list file or a VPC: one line per file and the total)."""

from __future__ import annotations

import argparse
import json
import math
import os

import numpy as np

from ._common import add_options

ORDER = 10


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "info",
        help="show format, point count, bounds, attributes and CRS of a file, files or point store",
        description=(
            "Describe PATH, a point cloud file (LAS/LAZ/COPC/PLY/E57/XYZ) or a point store, or the files "
            "simplify reads as one cloud: one line per file (format, count, bounds, CRS) and the total. The "
            "count and bounds come from the header where the format has one (LAS, E57 count); "
            "otherwise (PLY bounds, XYZ) the file is streamed once, chunk by chunk."
        ),
    )
    p.add_argument("path", metavar="PATH", help="file, point store (folder or fsspec URL), or files as one cloud: a "
                   "quoted glob ('tiles/*.laz'), a directory, a list file (.lst: one path per line, relative to the "
                   "list's folder) or a VPC (.vpc)")
    p.add_argument("--format", help="file format (default: from the extension)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    add_options(p, "info")
    p.set_defaults(func=run)


def _describe_store(path: str) -> dict:
    from ..store import PointStore

    store = PointStore.open(path)
    derived = []

    def walk(group, prefix=""):
        for name, node in group.members():
            full = f"{prefix}{name}"
            if hasattr(node, "members"):
                walk(node, full + "/")
            elif full not in store.dimensions:
                derived.append(full)

    walk(store.group)
    return {
        "path": path,
        "kind": "point store",
        "format": f"store (source {store.source_format})",
        "count": store.count,
        "bounds": store.bounds.tolist(),
        "attributes": {n: _dtype_text(*v) for n, v in store.dtypes.items() if n != "xyz"},
        "crs": _crs(store.header),
        "header": _short_header(store.header),
        "chunk_size": store.chunk_size,
        "derived_arrays": derived,
    }


def coordinate_text(value: float, scale: float | None = None) -> str:
    """A bound as text with every digit it has: ``1816492.71``, not ``1.81649e+06``.
    With a LAS *scale*, the decimals it gives; else the shortest text that reads back (in float32 for a float32
    value: ``-0.09469``)."""
    value = float(value)
    if scale is not None and scale > 0:
        return f"{value:.{max(0, math.ceil(-math.log10(scale) - 1e-9))}f}"
    single = np.float32(value)
    if np.isfinite(single) and float(single) == value:
        return str(single)
    return repr(value)


def _dtype_text(dtype, shape) -> str:
    return f"{np.dtype(dtype)}{list(shape) if shape else ''}"


def _crs(header: dict):
    crs = header.get("crs")
    if not crs:
        return None
    parts = [p for p in (crs.get("name"), f"EPSG:{crs['epsg']}" if crs.get("epsg") else None) if p]
    return ", ".join(parts) or (crs.get("wkt") or "")[:80] or None


def _short_header(header: dict) -> dict:
    keys = ("version", "point_format", "scales", "offsets", "system_identifier", "generating_software", "creation_date")
    out = {k: header[k] for k in keys if k in header}
    if "vlrs" in header:
        out["vlrs"] = [f"{v['user_id']}/{v['record_id']}" for v in header["vlrs"]]
        out["evlrs"] = [f"{v['user_id']}/{v['record_id']}" for v in header.get("evlrs", [])]
    for k in ("format", "comments", "columns", "delimiter", "scan_count"):
        if k in header:
            out[k] = header[k]
    return out


def _describe_file(path: str, format: str | None) -> dict:
    from ..io import open_reader

    with open_reader(path, format=format) as reader:
        header = reader.header
        count = reader.count
        if "mins" in header and "maxs" in header:
            bounds = [header["mins"], header["maxs"]]
        else:  # stream once for the bounds (and the count of XYZ)
            lo, hi, n = np.full(3, np.inf), np.full(3, -np.inf), 0
            for _, chunk in reader.chunks():
                xyz = chunk["xyz"]
                if len(xyz):
                    finite = xyz[np.isfinite(xyz).all(axis=1)]
                    if len(finite):
                        lo, hi = np.minimum(lo, finite.min(axis=0)), np.maximum(hi, finite.max(axis=0))
                n += len(xyz)
            count = n
            bounds = [lo.tolist(), hi.tolist()] if n else None
        return {
            "path": path,
            "kind": "file",
            "format": reader.format,
            "count": count,
            "bounds": bounds,
            "attributes": {n: _dtype_text(*v) for n, v in reader.dtypes.items() if n != "xyz"},
            "crs": _crs(header),
            "header": _short_header(header),
        }


def _describe_many(path: str, files: list[str], format: str | None) -> dict:
    """Each file of the cloud *path* (:func:`_describe_file`) and the total: files, count and bounds."""
    infos = [_describe_file(f, format) for f in files]
    counts = [i["count"] for i in infos]
    boxes = [i["bounds"] for i in infos]
    bounds = None
    if all(b is not None for b in boxes):
        bounds = [np.min([b[0] for b in boxes], axis=0).tolist(), np.max([b[1] for b in boxes], axis=0).tolist()]
    total = {"files": len(infos), "count": None if None in counts else int(sum(counts)), "bounds": bounds}
    return {"path": path, "kind": "files", "files": infos, "total": total}


def _range_text(bounds, scales) -> str:
    if not bounds:
        return ""
    return "".join(f", {axis} {coordinate_text(a, s)} .. {coordinate_text(b, s)}"
                   for axis, a, b, s in zip("xyz", *bounds, scales or [None] * 3))


def _print_many(info: dict) -> None:
    total = info["total"]
    print(f"{info['path']}: {total['files']} files read as one cloud")
    every = [f["header"].get("scales") for f in info["files"]]
    scales = np.min(every, axis=0).tolist() if all(every) else None  # the cloud's: the finest per axis
    for f in info["files"]:
        count = f"{f['count']:,} points" if f["count"] is not None else "points unknown"
        print(f"  {f['path']}: {f['format']}, {count}{_range_text(f['bounds'], f['header'].get('scales'))}, "
              f"CRS {f['crs'] or 'none'}")
    count = f"{total['count']:,} points" if total["count"] is not None else "points unknown"
    print(f"  total: {total['files']} files, {count}{_range_text(total['bounds'], scales)}")


def run(args: argparse.Namespace) -> int:
    from ..io.sources import expand_sources, is_many
    from ..store import is_store, local_path

    local = local_path(args.path)
    if is_store(args.path):
        info = _describe_store(args.path)
    elif local is not None and (os.path.isdir(local) or is_many(local)):
        named = args.path if "://" not in args.path else local  # the user's words in a message
        info = _describe_many(args.path, expand_sources(named), args.format)  # a directory without LAS/LAZ: refused
    elif local is None and is_many(args.path):  # a URL's glob, prefix, list or VPC
        info = _describe_many(args.path, expand_sources(args.path), args.format)
    else:
        info = _describe_file(args.path, args.format)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    if info["kind"] == "files":
        _print_many(info)
        return 0
    print(f"{info['path']}: {info['format']}")
    print(f"  points      {info['count']:,}" if info["count"] is not None else "  points      unknown")
    if info["bounds"]:
        lo, hi = info["bounds"]
        scales = info["header"].get("scales") or [None] * 3
        for axis, a, b, scale in zip("xyz", lo, hi, scales):
            print(f"  {axis}           {coordinate_text(a, scale)} .. {coordinate_text(b, scale)}")
    print(f"  CRS         {info['crs'] or 'none'}")
    print("  attributes  " + (", ".join(f"{k} ({v})" for k, v in info["attributes"].items()) or "none"))
    for k, v in info["header"].items():
        print(f"  {k:<11} {v}")
    if info.get("derived_arrays"):
        print("  derived     " + ", ".join(info["derived_arrays"]))
    return 0
