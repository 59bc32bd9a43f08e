"""The LAS header as a JSON-serialisable dict, and back; headers for non-LAS clouds.

:func:`header_to_dict`: version, point format with extra-bytes definitions,
scales, offsets, VLRs and EVLRs (data in base64), CRS, identification.
:func:`header_from_dict` rebuilds a ``laspy.LasHeader``; laspy updates counts
and bounds. The LASzip VLR is made afresh by laspy; COPC records (user id
"copc") are dropped with a warning: they describe the source's octree.
:func:`build_header` makes a header for PLY, E57 or XYZ clouds.
The chunked reader and writer are in :mod:`.las`.
"""

from __future__ import annotations

import base64
import datetime
import logging
import math
import re
from typing import Any
from uuid import UUID

import laspy
import numpy as np
from laspy.point.dims import DimensionInfo, DimensionKind
from laspy.vlrs.known import vlr_factory
from laspy.vlrs.vlrlist import VLRList

__all__ = ["header_to_dict", "header_from_dict", "build_header", "clip_to_dimension", "vlr_from_dict", "COPC_USER_ID",
           "LASZIP_USER_ID"]

logger = logging.getLogger(__name__)

COPC_USER_ID = "copc"
LASZIP_USER_ID = "laszip encoded"


# ---------------------------------------------------------------- header dict
def _b64(data: bytes) -> str:
    return base64.b64encode(bytes(data)).decode("ascii")


def _vlr_to_dict(vlr: Any) -> dict:
    try:
        data = vlr.record_data_bytes()
    except Exception:  # pragma: no cover - a known VLR that cannot re-serialise
        data = getattr(vlr, "record_data", b"")
    return {
        "user_id": vlr.user_id,
        "record_id": int(vlr.record_id),
        "description": vlr.description if isinstance(vlr.description, str) else vlr.description.decode(errors="replace"),
        "data": _b64(data),
    }


def _ascii(text: str) -> str:
    """*text* as laspy can write it (ASCII): a byte that did not decode (U+FFFD) becomes "?"."""
    return text.encode("ascii", errors="replace").decode("ascii")


def vlr_from_dict(d: dict) -> Any:
    """A laspy VLR (the known record type where laspy has one) from its :func:`header_to_dict` entry."""
    raw = laspy.VLR(_ascii(d["user_id"]), int(d["record_id"]), _ascii(d.get("description", "")),
                    base64.b64decode(d["data"]))
    return vlr_factory(raw)


def _arr_or_none(a: Any) -> list | None:
    return None if a is None else np.asarray(a).ravel().tolist()


def _wkt_name_and_epsg(wkt: str) -> tuple[str | None, int | None]:
    """The top-level name and EPSG code (the AUTHORITY at depth 1) of a WKT1/WKT2 string."""
    m = re.match(r'\s*\w+\s*[\[(]\s*"([^"]*)"', wkt)
    name = m.group(1) if m else None
    depth, epsg = 0, None
    i = 0
    while i < len(wkt):
        c = wkt[i]
        if c in "[(":
            depth += 1
        elif c in "])":
            depth -= 1
        elif depth == 1 and (wkt.startswith("AUTHORITY", i) or wkt.startswith("ID[", i)):
            a = re.match(r'(?:AUTHORITY|ID)\s*[\[(]\s*"EPSG"\s*,\s*"?(\d+)', wkt[i:])
            if a:
                epsg = int(a.group(1))
        i += 1
    return name, epsg


def _crs_of(vlrs: list) -> dict | None:
    """CRS from the WKT VLR (name, EPSG), else the GeoTIFF keys' EPSG; no pyproj needed."""
    crs: dict[str, Any] = {}
    for vlr in vlrs:
        name = type(vlr).__name__
        if name == "WktCoordinateSystemVlr" and "wkt" not in crs:
            wkt = vlr.string
            wkt = wkt if isinstance(wkt, str) else wkt.decode(errors="replace")
            crs["wkt"] = wkt.rstrip("\0")
            crs["name"], epsg = _wkt_name_and_epsg(crs["wkt"])
            if epsg:
                crs["epsg"] = epsg
    if "epsg" not in crs:
        for vlr in vlrs:
            if type(vlr).__name__ == "GeoKeyDirectoryVlr":
                keys = {k.id: k for k in vlr.geo_keys}
                for key_id in (3072, 2048):  # ProjectedCSType, GeographicType
                    key = keys.get(key_id)
                    if key is not None and key.tiff_tag_location == 0 and key.value_offset not in (0, 32767):
                        crs["epsg"] = int(key.value_offset)
                        break
    return crs or None


def header_to_dict(header: laspy.LasHeader, evlrs: list | None = None) -> dict:
    """A JSON-serialisable description of *header*, enough to rebuild it."""
    pf = header.point_format
    extra = []
    for dim in pf.extra_dimensions:
        extra.append(
            {
                "name": dim.name,
                "kind": int(dim.kind.value),
                "num_bits": int(dim.num_bits),
                "num_elements": int(dim.num_elements),
                "description": dim.description,
                "offsets": _arr_or_none(dim.offsets),
                "scales": _arr_or_none(dim.scales),
                "no_data": _arr_or_none(dim.no_data),
            }
        )
    vlrs = list(header.vlrs)
    evlrs = list(evlrs or [])
    date = header.creation_date
    return {
        "version": str(header.version),
        "point_format": int(pf.id),
        "point_size": int(pf.size),
        "point_count": int(header.point_count),
        "scales": [float(s) for s in header.scales],
        "offsets": [float(o) for o in header.offsets],
        "mins": [float(v) for v in header.mins],
        "maxs": [float(v) for v in header.maxs],
        "number_of_points_by_return": [int(v) for v in header.number_of_points_by_return],
        "file_source_id": int(header.file_source_id),
        "global_encoding": int(header.global_encoding.value),
        "uuid": str(header.uuid),
        "system_identifier": str(header.system_identifier),
        "generating_software": str(header.generating_software),
        "creation_date": date.isoformat() if date is not None else None,
        "compressed": bool(header.are_points_compressed),
        "extra_dimensions": extra,
        "vlrs": [_vlr_to_dict(v) for v in vlrs],
        "evlrs": [_vlr_to_dict(v) for v in evlrs],
        "extra_header_bytes": _b64(header.extra_header_bytes or b""),
        "extra_vlr_bytes": _b64(header.extra_vlr_bytes or b""),
        "crs": _crs_of(vlrs + evlrs),
    }


def _point_format(d: dict) -> laspy.PointFormat:
    pf = laspy.PointFormat(int(d["point_format"]))
    for e in d.get("extra_dimensions", []):
        opt = {k: (None if e.get(k) is None else np.asarray(e[k])) for k in ("offsets", "scales", "no_data")}
        pf.dimensions.append(
            DimensionInfo(
                name=e["name"],
                kind=DimensionKind(int(e["kind"])),
                num_bits=int(e["num_bits"]),
                num_elements=int(e["num_elements"]),
                is_standard=False,
                description=_ascii(e.get("description", "")),
                **opt,
            )
        )
    return pf


def _is_dropped(v: dict, path: str) -> bool:
    if v["user_id"] == LASZIP_USER_ID:
        return True  # laspy writes its own LASzip VLR for LAZ
    if v["user_id"] == COPC_USER_ID:  # a warning: shown without -v, the output is no longer COPC
        logger.warning(
            "%s: dropping COPC record (user_id 'copc', record_id %d): it describes the source's octree layout "
            "and is not valid in a re-ordered or plain LAS/LAZ file",
            path,
            v["record_id"],
        )
        return True
    return False


def _writable_version(version: str, point_format: int, path: str) -> str:
    """*version* when laspy writes it with *point_format* (not 1.0), else the lowest version that does (with a
    warning)."""
    from laspy.point.dims import VERSION_TO_POINT_FMT

    if point_format in VERSION_TO_POINT_FMT.get(str(version), ()):
        return str(version)
    chosen = min((v for v, formats in VERSION_TO_POINT_FMT.items() if point_format in formats), key=float)
    logger.warning("%s: LAS %s with point format %d cannot be written; writing LAS %s", path, version, point_format,
                   chosen)
    return chosen


def header_from_dict(d: dict, path: str = "") -> tuple[laspy.LasHeader, list]:
    """Rebuild a ``laspy.LasHeader`` and its EVLRs from :func:`header_to_dict`, without LASzip and COPC records."""
    point_format = _point_format(d)
    header = laspy.LasHeader(version=_writable_version(d["version"], point_format.id, path), point_format=point_format)
    header.scales = np.asarray(d["scales"], dtype=np.float64)
    header.offsets = np.asarray(d["offsets"], dtype=np.float64)
    header.file_source_id = int(d.get("file_source_id", 0))
    header.global_encoding = laspy.header.GlobalEncoding(int(d.get("global_encoding", 0)))
    header.uuid = UUID(d.get("uuid", str(UUID(int=0))))
    header.system_identifier = d.get("system_identifier", "OTHER")
    header.generating_software = d.get("generating_software", "cloudsieve")
    date = d.get("creation_date")
    header.creation_date = datetime.date.fromisoformat(date) if date else None
    header.extra_header_bytes = base64.b64decode(d.get("extra_header_bytes", ""))
    header.extra_vlr_bytes = base64.b64decode(d.get("extra_vlr_bytes", ""))
    vlrs = [vlr_from_dict(v) for v in d.get("vlrs", []) if not _is_dropped(v, path)]
    if any(type(v).__name__ == "ExtraBytesVlr" for v in vlrs) or not d.get("extra_dimensions"):
        # keep the source's VLRs verbatim (laspy would regenerate the extra-bytes VLR)
        header._vlrs = VLRList(vlrs)
    else:
        header.vlrs = vlrs  # regenerates the extra-bytes VLR from the point format
    evlrs = [vlr_from_dict(v) for v in d.get("evlrs", []) if not _is_dropped(v, path)]
    return header, evlrs


# ------------------------------------------------------- headers for non-LAS
_COLOR_SOURCES = (("red", "green", "blue"), ("colorRed", "colorGreen", "colorBlue"), ("r", "g", "b"))
_STANDARD_NAMES = {
    "intensity",
    "return_number",
    "number_of_returns",
    "classification",
    "scan_angle_rank",
    "user_data",
    "point_source_id",
    "gps_time",
}


def _color_source(dtypes: dict) -> tuple[str, str, str] | None:
    for names in _COLOR_SOURCES:
        if all(n in dtypes and dtypes[n][1] == () for n in names):
            return names
    return None


def _fits(dtype: np.dtype, target: np.dtype) -> bool:
    return np.can_cast(dtype, target, casting="safe")


def clip_to_dimension(values: np.ndarray, dimension: DimensionInfo) -> tuple[np.ndarray, tuple[int, int] | None]:
    """Integer *values* clipped to the range of a LAS *dimension* (laspy's, bit fields included), and the
    values' (min, max) when some lay outside it (None when all fit)."""
    lo, hi = int(dimension.min), int(dimension.max)
    if len(values) == 0:
        return values, None
    vmin, vmax = int(values.min()), int(values.max())
    return np.clip(values, lo, hi), ((vmin, vmax) if vmin < lo or vmax > hi else None)


def _extra_name(name: str, taken: set) -> str:
    out = re.sub(r"[^0-9A-Za-z_]", "_", name)[:32] or "extra"
    while out in taken:
        out = (out[:28] + "_x")[:32]
    taken.add(out)
    return out


def build_header(dtypes: dict, bounds: np.ndarray | None = None, path: str = "") -> tuple[dict, dict]:
    """A LAS header dict for a non-LAS cloud, and the attribute -> LAS name map.

    Point format 0 (1 with gps_time, 2 with colour, 3 with both); scale the
    finest power of ten keeping the bounds within int32; offsets at the
    minimum. Attributes with a LAS name and a compatible type go to the
    standard dimension; colour is scaled to 16 bits (8-bit x 257, floats 0..1
    x 65535); a float ``intensity`` goes to LAS intensity as round(v x 65535)
    and unchanged to the extra bytes ``intensity_``; wider integers are
    clipped ("int"); everything else becomes extra bytes (names sanitised).

    Returns ``(header, mapping)``: a :func:`header_to_dict` dict and
    ``(attribute, LAS dimension, conversion "copy" | "color8" | "unit16" | "int")``
    tuples, one attribute possibly to several dimensions.
    """
    color = _color_source(dtypes)
    has_gps = "gps_time" in dtypes and np.dtype(dtypes["gps_time"][0]).kind in "fiu"
    pf_id = 3 if (color and has_gps) else (2 if color else (1 if has_gps else 0))
    pf = laspy.PointFormat(pf_id)
    std = {d.name: np.dtype(d.dtype) if d.dtype is not None else np.dtype("u1") for d in pf.dimensions}
    sub_fields = {
        "return_number": 3,
        "number_of_returns": 3,
        "classification": 5,
        "scan_direction_flag": 1,
        "edge_of_flight_line": 1,
    }
    mapping: list[tuple[str, str, str]] = []
    taken = set(pf.dimension_names)
    extra: list[dict] = []
    for name, (dtype, shape) in dtypes.items():
        if name == "xyz":
            continue
        dtype = np.dtype(dtype)
        if color and name in color:
            las_name = ("red", "green", "blue")[color.index(name)]
            how = ("unit16" if dtype.kind == "f" else "color8" if dtype.itemsize == 1
                   else "copy" if _fits(dtype, np.dtype("u2")) else "int")
            mapping.append((name, las_name, how))
            continue
        if shape == () and name in _STANDARD_NAMES and name in std and dtype.kind in "uif":
            target = np.dtype("u1") if name in sub_fields else std[name]
            if (dtype.kind in "ui" and _fits(dtype, target)) or target.kind == "f":
                mapping.append((name, name, "copy"))
                continue
            if dtype.kind in "ui" and target.kind in "ui":
                mapping.append((name, name, "int"))
                continue
            if name == "intensity" and dtype.kind == "f":
                mapping.append((name, name, "unit16"))  # and, below, the exact value as extra bytes
        if dtype.kind not in "uif" or len(shape) > 1 or (shape and shape[0] > 3):
            logger.warning("%s: attribute %r (%s, %s) has no LAS representation; not written", path, name, dtype, shape)
            continue
        ename = _extra_name(name if name not in taken else name + "_", taken)
        k = shape[0] if shape else 1
        params = laspy.ExtraBytesParams(ename, f"{k}{dtype.str.lstrip('<>|=')}" if k > 1 else dtype, description=name[:32])
        info = DimensionInfo.from_extra_bytes_param(params)
        extra.append(
            {
                "name": info.name,
                "kind": int(info.kind.value),
                "num_bits": int(info.num_bits),
                "num_elements": int(info.num_elements),
                "description": info.description,
                "offsets": None,
                "scales": None,
                "no_data": None,
            }
        )
        mapping.append((name, ename, "copy"))
    if bounds is None:
        bounds = np.zeros((2, 3))
    bounds = np.asarray(bounds, dtype=np.float64)
    if not np.all(np.isfinite(bounds)):
        bounds = np.zeros((2, 3))
    offsets = [float(np.floor(v)) for v in bounds[0]]
    extent = float(np.max(np.abs(bounds - np.asarray(offsets))))
    scale = 10.0 ** math.ceil(math.log10(max(extent, 1e-9) / 2e9))
    scale = float(f"{scale:.0e}")
    header = {
        "version": "1.2",
        "point_format": pf_id,
        "scales": [scale] * 3,
        "offsets": offsets,
        "global_encoding": 0,
        "system_identifier": "cloudsieve",
        "generating_software": "cloudsieve",
        "creation_date": datetime.date.today().isoformat(),
        "extra_dimensions": extra,
        "vlrs": [],
        "evlrs": [],
    }
    if extra:
        header["version"] = "1.4"  # extra bytes are standard from LAS 1.4
    return header, mapping
