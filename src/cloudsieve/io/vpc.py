"""Virtual point clouds (VPC): the tile index PDAL wrench and QGIS read and write.

A ``.vpc`` is a STAC ItemCollection (GeoJSON FeatureCollection), one item
per file (wrench's ``vpc-spec.md``). :func:`write_vpc` writes wrench's
layout: ``proj:bbox``/``proj:geometry`` in the file's CRS, ``bbox``/``geometry``
in WGS 84 (:mod:`cloudsieve.io.vpc_crs`; the file's own coordinates when it
does not reproject), ``proj:wkt2`` ("" without CRS), ``proj:epsg`` when known.
:func:`read_vpc` resolves each item's data asset ``href`` against the VPC's folder.
"""

from __future__ import annotations

import datetime
import json
import logging
import os
from pathlib import Path

import numpy as np

from .. import storage
from ..errors import EmptyInputError, InputFormatError, InputNotFoundError, InvalidParameterError
from ..atomic import check_destination, write_text

__all__ = ["read_vpc", "read_vpc_items", "write_vpc", "describe_tile", "STAC_EXTENSIONS"]

logger = logging.getLogger(__name__)

#: the STAC extensions every item declares (as wrench writes them)
STAC_EXTENSIONS = [
    "https://stac-extensions.github.io/pointcloud/v1.0.0/schema.json",
    "https://stac-extensions.github.io/projection/v1.1.0/schema.json",
]


# ------------------------------------------------------------------ reading
def _data_asset(assets: dict) -> object:
    """The asset with the "data" role, else the first one (wrench takes the first)."""
    for asset in assets.values():
        if isinstance(asset, dict) and "data" in (asset.get("roles") or []):
            return asset
    return next(iter(assets.values()))


def read_vpc(path: str | os.PathLike) -> list[str]:
    """The files a ``.vpc`` lists, as absolute paths (a URL as it is), in its order.
    Raises InputNotFoundError (the VPC or a listed file is missing), InputFormatError (not a FeatureCollection, an
    item without a data asset, a file listed twice, a bad ``bbox``), EmptyInputError (no files)."""
    return [item["path"] for item in read_vpc_items(path)]


def _box(value, where: str) -> list[list[float | None]]:
    """[[xmin, ymin, zmin], [xmax, ymax, zmax]] of a STAC bbox of 6 numbers (4: z None)."""
    ok = isinstance(value, list) and len(value) in (4, 6) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)
    if not ok:
        raise InputFormatError(f"{where} is not 4 or 6 finite numbers: {json.dumps(value)[:80]}")
    if len(value) == 4:
        return [[float(value[0]), float(value[1]), None], [float(value[2]), float(value[3]), None]]
    return [[float(v) for v in value[:3]], [float(v) for v in value[3:]]]


def _native_bounds(f: dict, props: dict, where: str) -> list | None:
    """The item's bounds in its files' own CRS: ``proj:bbox``, else ``bbox`` for an item without CRS, else None."""
    if props.get("proj:bbox") is not None:
        return _box(props["proj:bbox"], f'{where}: its "proj:bbox"')
    has_crs = props.get("proj:wkt2") or props.get("proj:epsg") or props.get("proj:projjson")
    if f.get("bbox") is not None and not has_crs:  # no CRS: bbox is in the files' coordinates
        return _box(f["bbox"], f'{where}: its "bbox"')
    return None


def read_vpc_items(path: str | os.PathLike) -> list[dict]:
    """The items of a VPC, in its order: dicts of ``path`` (:func:`read_vpc`), ``count``, ``wkt`` and ``bounds``.
    ``wkt`` is ``proj:wkt2``, else ``EPSG:code``, else None; ``bounds`` [[xmin, ymin, zmin], [xmax, ymax, zmax]] in
    the file's CRS (``proj:bbox``, else ``bbox`` of an item without CRS, else None; z None for a 2D box). Raises as
    :func:`read_vpc`."""
    from . import check_input_file

    path = os.fspath(path)
    check_input_file(path)
    try:
        with storage.open_input(path) as fh:
            data = json.loads(fh.read().decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        where = f" at line {exc.lineno}, column {exc.colno}" if isinstance(exc, json.JSONDecodeError) else ""
        what = exc.msg if isinstance(exc, json.JSONDecodeError) else "not UTF-8 text"
        raise InputFormatError(f"{path}: not a VPC file: not valid JSON ({what}{where})") from None
    kind = data.get("type") if isinstance(data, dict) else type(data).__name__
    if kind != "FeatureCollection":
        raise InputFormatError(f'{path}: not a VPC file: its "type" is {kind!r}, not "FeatureCollection"')
    features = data.get("features")
    if not isinstance(features, list):
        raise InputFormatError(f'{path}: not a VPC file: no "features" list')
    if not features:
        raise EmptyInputError(f'{path}: the VPC lists no files (its "features" list is empty)')
    folder = storage.parent(path)
    out: list[dict] = []
    seen: dict[str, int] = {}
    for i, f in enumerate(features):
        if not isinstance(f, dict) or f.get("type") != "Feature":
            raise InputFormatError(f'{path}: feature {i} is not a STAC item ("type": "Feature")')
        name = f"feature {i} ({f['id']!r})" if "id" in f else f"feature {i}"
        assets = f.get("assets")
        if not isinstance(assets, dict) or not assets:
            raise InputFormatError(f'{path}: {name} has no "assets"')
        asset = _data_asset(assets)
        href = asset.get("href") if isinstance(asset, dict) else None
        if not isinstance(href, str) or not href:
            raise InputFormatError(f'{path}: {name}: its data asset has no "href"')
        if href.startswith("file://"):
            href = storage.local(href)
        # an absolute path or URL as it is; a relative href against the VPC's folder (or prefix)
        full = storage.join(folder, href)
        full = full if storage.is_url(full) else os.path.normpath(full)
        if not storage.exists(full):
            raise InputNotFoundError(f"{path}: {name} lists {full}, which does not exist")
        if full in seen:
            raise InputFormatError(f"{path}: features {seen[full]} and {i} both list {full}")
        seen[full] = i
        props = f.get("properties") if isinstance(f.get("properties"), dict) else {}
        count = props.get("pc:count")
        epsg = props.get("proj:epsg")
        out.append({
            "path": full,
            "count": int(count) if isinstance(count, int) and not isinstance(count, bool) else None,
            "wkt": props.get("proj:wkt2") or (f"EPSG:{epsg}" if epsg else None),
            "bounds": _native_bounds(f, props, f"{path}: {name}"),
        })
    return out


# ------------------------------------------------------------------ writing
def _datetime(day_year) -> str:
    """The STAC datetime of a LAS creation (day of year, year), with wrench's fallbacks (1970, January 1st)."""
    day, year = (int(v) for v in (day_year or (0, 0)))
    year = year if year > 0 else 1970
    last = datetime.date(year, 12, 31).timetuple().tm_yday
    day = day if 1 <= day <= last else 1
    date = datetime.date(year, 1, 1) + datetime.timedelta(days=day - 1)
    return f"{date.isoformat()}T00:00:00Z"


def _schemas(dtypes: dict) -> list[dict]:
    """``pc:schemas``: name, type ("signed", "unsigned", "floating") and size in bytes of each dimension."""
    kinds = {"i": "signed", "u": "unsigned", "f": "floating", "b": "unsigned"}
    out = []
    for name, (dtype, shape) in dtypes.items():
        dtype = np.dtype(dtype)
        if name == "xyz":
            out += [{"name": d, "type": "floating", "size": 8} for d in "XYZ"]
            continue
        out.append({"name": name, "type": kinds.get(dtype.kind, "unsigned"),
                    "size": int(dtype.itemsize * int(np.prod(shape or (1,))))})
    return out


def describe_tile(path: str | os.PathLike) -> dict:
    """The :func:`write_vpc` entry of a LAS/LAZ/COPC file, from its header (no point is read).
    Keys: ``path`` (absolute), ``count``, ``bounds``, ``wkt``, ``epsg``, ``datetime``, ``schemas``.
    InputFormatError for another format."""
    from . import detect_format, open_reader

    path = os.fspath(path)
    path = path if storage.is_url(path) else os.path.abspath(path)
    if detect_format(path) not in ("las", "laz", "copc"):
        raise InputFormatError(f"{path}: a VPC entry is described from a LAS/LAZ header; this is not a LAS/LAZ file")
    with open_reader(path) as reader:
        h, dtypes = reader.header, reader.dtypes
    crs = h.get("crs") or {}
    wkt, epsg = crs.get("wkt"), crs.get("epsg")
    if not wkt and epsg:  # GeoTIFF keys only
        from .vpc_crs import geotiff_wkt

        wkt, epsg = geotiff_wkt(path)
    return {
        "path": path,
        "count": int(h["point_count"]),
        "bounds": [list(map(float, h["mins"])), list(map(float, h["maxs"]))],
        "wkt": wkt,
        "epsg": epsg,
        "datetime": _datetime(h.get("creation_day_year")),
        "schemas": _schemas(dtypes),
    }


def _feature(entry: dict, folder: str, i: int, unprojected: dict) -> dict:
    """The STAC item of *entry*; a CRS that does not reproject to WGS 84 is added to *unprojected* with the reason."""
    try:
        tile = os.fspath(entry["path"])
        tile = tile if storage.is_url(tile) else os.path.abspath(tile)
        count = int(entry["count"])
        lo, hi = (np.asarray(entry["bounds"], dtype=np.float64).reshape(2, 3)).tolist()
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidParameterError(
            f"VPC entry {i} needs 'path', 'count' and 'bounds' [[xmin, ymin, zmin], [xmax, ymax, zmax]]: {exc}") from None
    if not np.all(np.isfinite(lo + hi)):
        raise InvalidParameterError(f"VPC entry {i} ({tile}): bounds {[lo, hi]} are not finite")
    if storage.is_url(folder):  # a tile under the VPC's prefix: relative; elsewhere: its URL
        rel = tile[len(folder.rstrip("/")) + 1:] if tile.startswith(folder.rstrip("/") + "/") else None
    else:
        rel = os.path.relpath(tile, folder).replace(os.sep, "/")
    bbox = [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]]
    ring = [[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]], [lo[0], lo[1]]]
    geometry = {"type": "Polygon", "coordinates": [ring]}
    wkt = entry.get("wkt") or ""
    wgs84_bbox, wgs84_geometry = bbox, geometry  # no CRS: the files' own coordinates, as wrench writes them
    if wkt:
        from .vpc_crs import wgs84_extent

        try:
            wgs84_bbox, wgs84_geometry = wgs84_extent(wkt, lo, hi)
        except ValueError as exc:
            unprojected.setdefault(wkt, str(exc))
    props = {
        "datetime": entry.get("datetime") or _datetime(None),
        "pc:count": count,
        "pc:type": "lidar",
        "pc:encoding": "?",
        "pc:schemas": list(entry.get("schemas") or []),
        "proj:wkt2": wkt,
    }
    if entry.get("epsg"):
        props["proj:epsg"] = int(entry["epsg"])
    props["proj:geometry"] = geometry
    props["proj:bbox"] = bbox
    name = storage.name(tile)
    return {
        "type": "Feature",
        "stac_version": "1.0.0",
        "stac_extensions": list(STAC_EXTENSIONS),
        "id": str(entry.get("id") or Path(name).stem),
        "geometry": wgs84_geometry,
        "bbox": wgs84_bbox,
        "properties": props,
        "links": [],
        # wrench resolves "./" hrefs only
        "assets": {"data": {"href": tile if rel is None else "./" + rel, "roles": ["data"]}},
    }


def write_vpc(path: str | os.PathLike, tiles: list[dict], *, overwrite: bool = False) -> str:
    """Write a VPC listing *tiles* (under a temporary name, then renamed); returns *path*.
    Each entry of *tiles*: ``path``, ``count``, ``bounds`` [[xmin, ymin, zmin], [xmax, ymax, zmax]], optionally
    ``wkt``, ``epsg``, ``datetime``, ``schemas``, ``id`` (default: the file's stem); :func:`describe_tile` makes
    one. Raises InvalidParameterError (an entry without path, count or finite bounds), DestinationExistsError,
    DestinationNotWritableError."""
    path = os.fspath(path)
    folder = storage.parent(path)
    unprojected: dict[str, str] = {}
    doc = {"type": "FeatureCollection", "features": [_feature(t, folder, i, unprojected)
                                                     for i, t in enumerate(tiles)]}
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    check_destination(path, overwrite)
    if storage.is_url(path):  # one request: the object appears whole or not at all
        storage.write_bytes(path, text.encode("utf-8"))
    else:
        write_text(path, text)
    for wkt, reason in unprojected.items():
        logger.warning("%s: the CRS %.60s... does not reproject to WGS 84 (%s): bbox and geometry are in the "
                       "files' own coordinates", path, wkt, reason)
    logger.info("wrote %s listing %d files", path, len(tiles))
    return path
