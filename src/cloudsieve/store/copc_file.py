"""The bytes of a COPC 1.0 file (https://copc.io): header, point records, LAZ chunks, hierarchy.

A LAS 1.4 file of point format 6, 7 or 8 (PDAL's choice: 8 with NIR, 7 with
RGB), the ``copc`` info VLR first, one variable-size LAZ chunk per octree
node, the hierarchy in EVLR ``copc`` 1000 (:mod:`.copc_hierarchy`). Formats
0-5 convert field by field (``scan_angle = round(scan_angle_rank / 0.006)``,
as PDAL); wave packet fields are dropped, with a warning.
"""

from __future__ import annotations

import base64
import io
import logging
import struct
from typing import BinaryIO

import laspy
import lazrs
import numpy as np
from laspy.vlrs.vlrlist import VLRList

from .. import storage
from ..errors import CorruptInputError, InputFormatError
from ..io.las_header import COPC_USER_ID, LASZIP_USER_ID, build_header, clip_to_dimension, header_from_dict
from ..io.las_records import decode_xyz
from .copc_hierarchy import ENTRY_DTYPE, ROOT_PAGE_NODES, hierarchy_pages

__all__ = ["copc_header", "point_records", "compress", "record_stats", "merge_stats", "write_copc", "laz_vlr",
           "SPAN"]

logger = logging.getLogger(__name__)

#: the root's spacing is its edge / SPAN (voxels along an axis of a node's grid)
SPAN = 128
_WAVE = ("wavepacket_index", "wavepacket_offset", "wavepacket_size", "return_point_wave_location",
         "x_t", "y_t", "z_t")
_LAS14_HEADER_SIZE = 375
_WKT_ENCODING = 0x10


def _output_format(point_format: int) -> int:
    names = set(laspy.PointFormat(point_format).dimension_names)
    return 8 if "nir" in names else (7 if "red" in names else 6)


def copc_header(header: dict, dtypes: dict, source_format: str | None, bounds: np.ndarray | None = None,
                path: str = "") -> tuple[dict, list[tuple[str, str, str]]]:
    """The COPC header (dict) of a store's cloud, and how each attribute goes into the records.

    *header*, *dtypes*, *source_format*: the store's (a fresh header from
    :func:`cloudsieve.io.las_header.build_header` and *bounds* for a non-LAS
    source); *path*: the destination, for messages. The header is LAS 1.4,
    format 6/7/8 with the source's extra bytes, the WKT bit set, and the
    source's VLRs and EVLRs but the LASzip and COPC ones. The mapping lists
    (store attribute, LAS dimension, conversion "copy" | "color8" | "unit16" |
    "int" | "angle").
    """
    if source_format in ("las", "laz", "copc") or (source_format is None and "point_format" in header):
        d = dict(header)
        mapping = [(n, n, "copy") for n in dtypes if n != "xyz"]
    else:
        d, mapping = build_header(dtypes, bounds, path)
    dropped = [n for n, las, _ in mapping if las in _WAVE]
    if dropped:
        logger.warning("%s: COPC has no wave packets: dropping %s", path, ", ".join(dropped))
    mapping = [(n, "scan_angle", "angle") if las == "scan_angle_rank" else (n, las, how)
               for n, las, how in mapping if las not in _WAVE]
    d["point_format"] = _output_format(int(d["point_format"]))
    d["version"] = "1.4"
    # GPS time type and synthetic return numbers kept; no waveform; WKT (LAS 1.4 for formats 6-10)
    d["global_encoding"] = (int(d.get("global_encoding", 0)) & 0x09) | _WKT_ENCODING
    for key in ("vlrs", "evlrs"):
        d[key] = [v for v in d.get(key, []) if v["user_id"] not in (COPC_USER_ID, LASZIP_USER_ID)]
    for key in ("extra_header_bytes", "extra_vlr_bytes"):
        if d.get(key):
            logger.warning("%s: dropping the source's %s (COPC puts the info VLR right after the header)", path,
                           key.replace("_", " "))
            d[key] = ""
    wkt = any(v["user_id"] == "LASF_Projection" and v["record_id"] == 2112 for v in d["vlrs"] + d["evlrs"])
    if not wkt and any(v["user_id"] == "LASF_Projection" for v in d["vlrs"] + d["evlrs"]):
        d["vlrs"] = d["vlrs"] + _wkt_from_geotiff(d, path)
    return d, mapping


def _wkt_from_geotiff(d: dict, path: str) -> list[dict]:
    """A WKT VLR (header dict entry) for a CRS given by GeoTIFF keys only, or none (with a warning).

    Point formats 6-10 take their CRS from a WKT VLR; written as WKT1 (GDAL's
    flavour, as PDAL) through pyproj. The GeoTIFF keys are kept too.
    """
    try:
        import pyproj  # noqa: F401 - laspy's parse_crs needs it
    except ImportError:
        logger.warning("%s: the source's CRS is in GeoTIFF keys only and pyproj is not installed: no WKT VLR "
                       "written (pip install pyproj)", path)
        return []
    header, _ = header_from_dict(d, path)
    try:
        crs = header.parse_crs()
    except Exception as exc:  # a key set pyproj cannot read
        crs, reason = None, str(exc)
    else:
        reason = "no EPSG code in the keys"
    if crs is None:
        logger.warning("%s: cannot turn the source's GeoTIFF keys into a WKT CRS (%s): no WKT VLR written", path,
                       reason)
        return []
    data = crs.to_wkt("WKT1_GDAL").encode("ascii", errors="replace") + b"\0"
    return [{"user_id": "LASF_Projection", "record_id": 2112, "description": "OGC WKT (from GeoTIFF keys)",
             "data": base64.b64encode(data).decode("ascii")}]


def laz_vlr(header: laspy.LasHeader) -> lazrs.LazVlr:
    """The LASzip VLR of *header*'s point format, with variable-size chunks (one per node)."""
    pf = header.point_format
    return lazrs.LazVlr.new_for_compression(pf.id, pf.num_extra_bytes, True)


def point_records(arrays: dict[str, np.ndarray], header: laspy.LasHeader,
                  mapping: list[tuple[str, str, str]]) -> np.ndarray:
    """The packed point records (n,) of *arrays* (store attributes, "xyz" float64) in *header*'s format.

    X/Y/Z are ``round((xyz - offset) / scale)``: the source's integers.
    """
    xyz = np.asarray(arrays["xyz"], dtype=np.float64)
    n = len(xyz)
    rec = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    for i, dim in enumerate("XYZ"):
        raw = np.round((xyz[:, i] - header.offsets[i]) / header.scales[i])
        if n and (not np.all(np.isfinite(raw)) or raw.min() < -(2**31) or raw.max() > 2**31 - 1):
            raise InputFormatError(f"{'xyz'[i]} values {xyz[:, i].min()}..{xyz[:, i].max()} do not fit LAS int32 "
                                   f"with scale {header.scales[i]} and offset {header.offsets[i]}")
        rec.array[dim] = raw.astype(np.int32)
    packed = set(rec.array.dtype.names)
    for name, las_name, how in mapping:
        if name not in arrays:
            continue
        values = np.asarray(arrays[name])
        if how == "color8":
            values = values.astype(np.uint16) * np.uint16(257)
        elif how == "unit16":
            values = np.clip(np.round(np.nan_to_num(values.astype(np.float64)) * 65535.0), 0, 65535).astype(np.uint16)
        elif how == "int":  # an integer wider than the LAS dimension: clipped to its range
            values = clip_to_dimension(values, header.point_format.dimension_by_name(las_name))[0]
        elif how == "angle":  # PDAL: std::round(float(rank) / .006f)
            values = np.round(values.astype(np.float32) / np.float32(0.006)).astype(np.int16)
        if las_name in packed:
            rec.array[las_name] = values
        else:
            rec[las_name] = values
    return rec.array


def compress(records: np.ndarray, vlr: lazrs.LazVlr) -> bytes:
    """*records* as one LAZ chunk (the bytes between a LAZ file's chunk-table offset and its chunk table)."""
    data = lazrs.compress_points(vlr, np.ascontiguousarray(records).view(np.uint8).ravel(), False)
    table = struct.unpack_from("<q", data, 0)[0]
    return bytes(data[8:table])


def record_stats(records: np.ndarray, point_format: laspy.PointFormat) -> dict:
    """Header statistics of *records*: count, points by return (15), X/Y/Z integer bounds, GPS time range."""
    n = len(records)
    stats = {"count": n, "by_return": [0] * 15, "mins": None, "maxs": None, "gps": None}
    if n == 0:
        return stats
    rec = laspy.PackedPointRecord(records, point_format)
    returns = np.asarray(rec["return_number"]).astype(np.int64)
    stats["by_return"] = np.bincount(returns, minlength=16)[1:16].tolist()
    stats["mins"] = [int(records[d].min()) for d in "XYZ"]
    stats["maxs"] = [int(records[d].max()) for d in "XYZ"]
    gps = records["gps_time"]
    stats["gps"] = [float(gps.min()), float(gps.max())]
    return stats


def merge_stats(parts: list[dict]) -> dict:
    """The statistics of the union of the records of *parts* (:func:`record_stats` results)."""
    out = {"count": 0, "by_return": [0] * 15, "mins": None, "maxs": None, "gps": None}
    for p in parts:
        if not p["count"]:
            continue
        out["count"] += p["count"]
        out["by_return"] = [a + b for a, b in zip(out["by_return"], p["by_return"])]
        for key, pick in (("mins", min), ("maxs", max)):
            out[key] = list(p[key]) if out[key] is None else [pick(a, b) for a, b in zip(out[key], p[key])]
        out["gps"] = list(p["gps"]) if out["gps"] is None else [min(out["gps"][0], p["gps"][0]),
                                                                max(out["gps"][1], p["gps"][1])]
    return out


def _evlr(user_id: str, record_id: int, description: str, data: bytes) -> bytes:
    return struct.pack("<H16sHQ32s", 0, user_id.encode("ascii", errors="replace"), record_id, len(data),
                       description.encode("ascii", errors="replace")[:32]) + data


def _runs(sources: np.ndarray, offsets: np.ndarray, nbytes: np.ndarray) -> list[tuple[int, int, int]]:
    """The chunks as (source, offset, bytes) runs: chunks that follow each other in one source make one run."""
    runs: list[list[int]] = []
    for src, off, nb in zip(sources, offsets, nbytes):
        src, off, nb = int(src), int(off), int(nb)
        if runs and runs[-1][0] == src and runs[-1][1] + runs[-1][2] == off:
            runs[-1][2] += nb
        else:
            runs.append([src, off, nb])
    return [(s, o, n) for s, o, n in runs]


def _copy(dst: BinaryIO, path: str, offset: int, nbytes: int) -> None:
    """Append *nbytes* of the scratch file *path* from *offset* to *dst*, in reads of at most READ_BLOCK."""
    done = 0
    while done < nbytes:
        step = min(nbytes - done, storage.READ_BLOCK)
        block = storage.read_range(path, offset + done, step)
        if len(block) != step:
            raise CorruptInputError(f"scratch file {path} is truncated: {nbytes - done - len(block)} bytes missing "
                                    f"at {offset + done + len(block)}")
        dst.write(block)
        done += step


def write_copc(path: str, header: dict, origin: np.ndarray, size: float, nodes: dict[str, np.ndarray],
               sources: list[str], stats: dict, root_nodes: int = ROOT_PAGE_NODES) -> int:
    """Write the COPC file *path* from node chunks already compressed into *sources*; returns bytes written.

    The bytes go out front to back (header fields and chunk table computed
    first), so a URL is one upload (:func:`cloudsieve.storage.open_output`)
    that appears complete or not at all. Consecutive chunks of one source
    are copied as one run.

    Parameters
    ----------
    header : dict
        From :func:`copc_header`.
    origin, size
        The root cube (:func:`cloudsieve.store.octree.root_cube`).
    nodes : dict of str to ndarray
        One entry per node, in file order: "depth", "x", "y", "z" (its key),
        "count", "nbytes", "source" (index into *sources*) and "offset".
    sources : list of str
        Scratch files holding the chunks (local paths or URLs).
    stats : dict
        :func:`merge_stats` of every point.
    root_nodes : int
        At most this many nodes in one hierarchy page (:mod:`.copc_hierarchy`).
    """
    hdr, evlrs = header_from_dict(header, path)
    vlr = laz_vlr(hdr)
    count = np.asarray(nodes["count"], dtype=np.int64)
    nbytes = np.asarray(nodes["nbytes"], dtype=np.int64)
    table = io.BytesIO()
    lazrs.write_chunk_table(table, [(int(c), int(b)) for c, b in zip(count, nbytes)], vlr)
    table_bytes = table.getvalue()

    def header_bytes(info: bytes) -> bytes:
        hdr._vlrs = VLRList([laspy.VLR(COPC_USER_ID, 1, "copc info", info),
                             laspy.VLR(LASZIP_USER_ID, 22204, "lazrs variable size chunks", vlr.record_data()),
                             *[v for v in hdr.vlrs if v.user_id not in (COPC_USER_ID, LASZIP_USER_ID)]])
        out = io.BytesIO()
        hdr.write_to(out)
        data = bytearray(out.getvalue())
        day_year = header.get("creation_day_year")
        if header.get("creation_date") is None:  # laspy would write the current date: keep the source's bytes
            day, year = day_year if day_year else (0, 0)
            data[90:94] = int(day).to_bytes(2, "little") + int(year).to_bytes(2, "little")
        return bytes(data)

    hdr.are_points_compressed = True
    hdr.point_count = int(stats["count"])
    hdr.number_of_points_by_return = np.asarray(stats["by_return"], dtype=np.int64)
    scales, offsets = np.asarray(hdr.scales), np.asarray(hdr.offsets)
    if stats["count"]:
        hdr.mins, hdr.maxs = decode_xyz(np.array([stats["mins"], stats["maxs"]], dtype=np.float64), scales, offsets)
    else:
        hdr.mins = hdr.maxs = np.zeros(3)
    hdr.number_of_evlrs = 1 + len(evlrs)
    first = header_bytes(bytes(160))
    if len(first) < _LAS14_HEADER_SIZE or first[_LAS14_HEADER_SIZE + 2:_LAS14_HEADER_SIZE + 6] != b"copc":
        raise InputFormatError(f"cannot write {path}: the COPC info VLR is not right after the header")
    points_at = len(first)
    chunk_at = points_at + 8 + np.concatenate([[0], np.cumsum(nbytes)])
    table_at = int(chunk_at[-1])
    hdr.start_of_first_evlr = evlr_at = table_at + len(table_bytes)
    depth = np.asarray(nodes["depth"], dtype=np.int64)
    entries = np.zeros(max(len(depth), 1), dtype=ENTRY_DTYPE)  # an empty cloud: the root, without points
    if len(depth):
        for name in ("x", "y", "z"):
            entries[name] = nodes[name]
        entries["d"], entries["offset"], entries["nbytes"], entries["count"] = depth, chunk_at[:-1], nbytes, count
    hierarchy, root_size = hierarchy_pages(entries, evlr_at + 60, root_nodes=root_nodes)
    half = size / 2.0
    centre = np.asarray(origin, dtype=np.float64) + half
    gps = stats["gps"] or [0.0, 0.0]
    info = struct.pack("<5d2Q2d11Q", *centre, half, size / SPAN, evlr_at + 60, root_size, *gps, *([0] * 11))
    head = header_bytes(info)
    if len(head) != points_at:  # pragma: no cover - the info VLR has a fixed size
        raise InputFormatError(f"cannot write {path}: the header changed size")
    out = storage.open_output(path)
    try:
        with storage.remote_errors(path, writing=True):
            out.write(head)
            out.write(struct.pack("<q", table_at))
            for src, off, nb in _runs(nodes["source"], nodes["offset"], nbytes):
                _copy(out, sources[src], off, nb)
            out.write(table_bytes)
            out.write(_evlr(COPC_USER_ID, 1000, "EPT hierarchy", hierarchy))
            for v in evlrs:
                out.write(_evlr(v.user_id, int(v.record_id), v.description if isinstance(v.description, str)
                                else v.description.decode(errors="replace"), v.record_data_bytes()))
            written = out.tell()
            out.close()  # a URL: the upload completes here
    except BaseException:
        _discard(out)  # also after a failed close: a multipart upload left open is aborted
        raise
    return written


def _discard(out) -> None:
    """:func:`cloudsieve.storage.discard` *out*, then mark an fsspec file closed: its finaliser would
    otherwise flush the discarded buffer (an error printed when it is collected)."""
    storage.discard(out)
    if not getattr(out, "closed", True):  # a local file is closed by discard
        try:
            out.closed = True
        except AttributeError:  # pragma: no cover - a file object whose ``closed`` cannot be set
            pass
