"""The read plan of LAS/LAZ/COPC sources: headers only, read by the driver.

The files of one cloud (:func:`cloudsieve.io.sources.expand_sources`) must share point format, extra-bytes
dimensions and CRS records, else :class:`~cloudsieve.errors.MismatchedInputsError`. Per axis the finest scale and
the first offset are kept; a file is re-quantised, ``X' = X * (s / s') + (o - o') / s'``, only when both factors
are integers (exact). VLRs and EVLRs: the first file's, then every later one not already present; the version is
the highest. Rows are cut into pieces for :func:`.las_records.read_pieces`.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass

import numpy as np

from ..errors import MismatchedInputsError

__all__ = ["LasPlan", "plan_las", "is_las_source", "crs_label", "LAS_FORMATS"]

#: formats whose records the task ingest copies as LAS integers
LAS_FORMATS = ("las", "laz", "copc")
_PROJECTION = "LASF_Projection"
_DROPPED = ("laszip encoded", "copc")


def is_las_source(paths: list[str]) -> bool:
    """True when every file of *paths* is LAS, LAZ or COPC (by extension)."""
    from . import detect_format

    return all(detect_format(p) in LAS_FORMATS for p in paths)


@dataclass
class LasPlan:
    """The files of one LAS cloud and how their records map to the store.
    ``counts`` (F,) int64 points per file; ``header`` the store's header
    (:func:`cloudsieve.io.las_header.header_to_dict` layout, merged by the module's rules); ``dtypes`` "xyz" first;
    ``scale``, ``offset`` (3,) the store's encoding; ``factors`` (F, 2, 3) int64 per file the integer multiplier
    and addend; ``format`` the first file's."""

    paths: list[str]
    counts: np.ndarray
    header: dict
    dtypes: dict
    scale: np.ndarray
    offset: np.ndarray
    factors: np.ndarray
    format: str

    @property
    def total(self) -> int:
        return int(self.counts.sum())

    def tasks(self, chunk_size: int, chunks_per_task: int = 1) -> list[tuple[int, int, list[tuple]]]:
        """The ingest's tasks: ``(row_start, row_stop, pieces)``, each a whole number of store chunks.
        *pieces* are ``(path, first, n, factors)``: *n* points of *path* from point *first*, with its
        re-quantisation factors. Every store chunk is written by exactly one task."""
        step = int(chunk_size) * int(chunks_per_task)
        ends = np.cumsum(self.counts)
        starts = ends - self.counts
        out = []
        for lo in range(0, self.total, step):
            hi = min(lo + step, self.total)
            first, last = np.searchsorted(ends, lo, side="right"), np.searchsorted(starts, hi, side="left")
            pieces = []
            for f in range(int(first), int(last)):
                a, b = max(lo, int(starts[f])), min(hi, int(ends[f]))
                if b > a:
                    pieces.append((self.paths[f], a - int(starts[f]), b - a, self.factors[f].tolist()))
            out.append((lo, hi, pieces))
        return out


def _projection(header: dict) -> list:
    return [(v["record_id"], v["data"]) for v in header["vlrs"] + header["evlrs"] if v["user_id"] == _PROJECTION]


def _attributes(header: dict) -> list:
    return [(e["name"], e["kind"], e["num_elements"]) for e in header.get("extra_dimensions", [])]


def _integer(value: float, before: str, after: str) -> int:
    """*value* as an integer; when it is none, MismatchedInputsError ``before value after, not a whole number``."""
    near = round(value)
    if not math.isfinite(value) or abs(value - near) > 1e-6 * max(1.0, abs(value)):
        raise MismatchedInputsError(
            f"{before} {value:.9g} {after}, not a whole number: its records are not exactly representable; "
            f"re-quantise the files to one scale and offset first")
    return int(near)


def _geotiff_citation(header: dict) -> str | None:
    """The citation of a header's GeoTIFF keys (PCS, else GT, else geographic citation), or None."""
    records = {record_id: base64.b64decode(data) for record_id, data in _projection(header)}
    if 34735 not in records or 34737 not in records:  # GeoKeyDirectoryTag, GeoAsciiParamsTag
        return None
    keys = np.frombuffer(records[34735][: len(records[34735]) // 2 * 2], dtype="<u2")
    text = records[34737].decode("ascii", errors="replace")
    found = {int(k[0]): text[int(k[3]):int(k[3]) + int(k[2])].strip("|\0 ")
             for k in keys[4:].reshape(-1, 4)[: int(keys[3]) if len(keys) > 3 else 0] if int(k[1]) == 34737}
    return next((found[k] for k in (3073, 1026, 2049) if found.get(k)), None)


def crs_label(header: dict) -> str:
    """The CRS of a LAS *header* in words: its WKT's name (and EPSG code), else its GeoTIFF keys' EPSG code
    (``EPSG:2992``), else their citation (``GeoTIFF keys without an EPSG code: "..."``), else what its
    projection records lack; "none" without projection records."""
    crs = header.get("crs") or {}
    name, epsg = crs.get("name"), crs.get("epsg")
    if name:
        return f"{name}, EPSG:{epsg}" if epsg else name
    if epsg:
        return f"EPSG:{epsg}"
    records = _projection(header)
    if not records:
        return "none"
    if any(record_id == 34735 for record_id, _ in records):
        citation = _geotiff_citation(header)
        return "GeoTIFF keys without an EPSG code" + (f': "{citation}"' if citation else "")
    return "projection records without a WKT name or EPSG code"


def _merge_records(headers: list[dict], key: str) -> list[dict]:
    seen = {(v["user_id"], v["record_id"], v["data"]) for v in headers[0][key]}
    out = list(headers[0][key])
    for h in headers[1:]:
        for v in h[key]:
            ident = (v["user_id"], v["record_id"], v["data"])
            if ident not in seen and v["user_id"] not in _DROPPED:
                seen.add(ident)
                out.append(v)
    return out


def plan_las(paths: list[str]) -> LasPlan:
    """Read the headers of *paths* (LAS/LAZ/COPC) and plan their ingest as one cloud.
    Raises MismatchedInputsError (the module's rules), or the errors of :func:`cloudsieve.io.open_reader`."""
    from . import open_reader

    headers, counts, dtypes, fmt = [], [], None, None
    for path in paths:
        with open_reader(path) as reader:
            headers.append(reader.header)
            counts.append(int(reader.count))
            if dtypes is None:
                dtypes, fmt = reader.dtypes, reader.format
    first = headers[0]
    for path, h in zip(paths[1:], headers[1:]):
        if h["point_format"] != first["point_format"]:
            raise MismatchedInputsError(
                f"{path}: point format {h['point_format']}, but {paths[0]} has {first['point_format']}: the files "
                f"of one cloud must share their point format")
        if _attributes(h) != _attributes(first):
            raise MismatchedInputsError(
                f"{path}: extra attributes {[a[0] for a in _attributes(h)]}, but {paths[0]} has "
                f"{[a[0] for a in _attributes(first)]}: the files of one cloud must share their attributes")
        if _projection(h) != _projection(first):
            crs, crs0 = crs_label(h), crs_label(first)
            what = f"its CRS ({crs}) differs from" if crs != crs0 else f"its CRS records ({crs}) differ from"
            raise MismatchedInputsError(
                f"{path}: {what} that of {paths[0]} ({crs0}): the files of one cloud must share their CRS; "
                f"reproject them first")
    scales = np.array([h["scales"] for h in headers], dtype=np.float64)
    offsets = np.array([h["offsets"] for h in headers], dtype=np.float64)
    scale, offset = scales.min(axis=0), offsets[0]
    factors = np.zeros((len(paths), 2, 3), dtype=np.int64)
    finest = [paths[int(np.argmin(scales[:, i]))] for i in range(3)]  # the first file of the finest scale
    for f, path in enumerate(paths):
        for i, axis in enumerate("xyz"):
            step = f"of the cloud's {axis} scale {scale[i]:g} (the finest, from {finest[i]})"
            factors[f, 0, i] = _integer(scales[f, i] / scale[i], f"{path}: the {axis} scale {scales[f, i]:g} is",
                                        f"steps {step}")
            factors[f, 1, i] = _integer((offsets[f, i] - offset[i]) / scale[i],
                                        f"{path}: the {axis} offset {offsets[f, i]:g} is",
                                        f"steps {step} from the cloud's {axis} offset {offset[i]:g} (from {paths[0]})")
    header = dict(first)
    header.update({
        "version": max((h["version"] for h in headers), key=lambda v: tuple(int(x) for x in v.split("."))),
        "point_count": int(sum(counts)),
        "scales": scale.tolist(),
        "offsets": offset.tolist(),
        "vlrs": _merge_records(headers, "vlrs"),
        "evlrs": _merge_records(headers, "evlrs"),
    })
    return LasPlan(list(paths), np.asarray(counts, dtype=np.int64), header, dtypes, scale, offset, factors, fmt)
