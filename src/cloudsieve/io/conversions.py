"""What a conversion between formats drops or maps, said once per written file.

:func:`conversion_note` names each field the destination has no place for
(a LAS source's CRS and VLRs, a PLY source's comments and other elements)
and each attribute renamed or converted (float intensity, 8-bit colour,
names LAS does not take); :class:`~cloudsieve.io._base.Writer` logs it as
one warning. A format written to itself says nothing.
"""

from __future__ import annotations

__all__ = ["conversion_note"]

_LAS = ("las", "laz", "copc")
#: record ids of the CRS's VLRs (WKT, GeoTIFF keys; LASF_Projection's or liblas')
_CRS_RECORDS = {2111, 2112, 34735, 34736, 34737}
#: VLRs of the file format itself (extra-bytes descriptions, LAZ compression, COPC): nothing of the cloud's
_FORMAT_USERS = {"LASF_Spec", "laszip encoded", "copc"}
_HOW = {
    "color8": "8-bit values x 257 to 16 bits",
    "unit16": "values 0..1 x 65535 to 16 bits, clipped",
}


def _source_family(source_format: str | None, header: dict) -> str | None:
    if source_format in _LAS or (source_format is None and "point_format" in header):
        return "las"
    if source_format == "ply" or (source_format is None and "elements" in header):
        return "ply"
    return source_format


def _crs_text(crs: dict) -> str:
    parts = [p for p in (crs.get("name"), f"EPSG:{crs['epsg']}" if crs.get("epsg") else None) if p]
    return ", ".join(parts) or "WKT"


def _las_notes(header: dict, out: str) -> list[str]:
    """A LAS header written to another format: its CRS and its other (E)VLRs have no place there."""
    notes = []
    if header.get("crs"):
        notes.append(f"the CRS ({_crs_text(header['crs'])}): {out.upper()} has no CRS")
    others = [f"{v['user_id']}/{v['record_id']}" for v in [*header.get("vlrs", []), *header.get("evlrs", [])]
              if v["record_id"] not in _CRS_RECORDS and v["user_id"] not in _FORMAT_USERS]
    if others:
        notes.append(f"{len(others)} other VLR(s) ({', '.join(others)})")
    return notes


def _ply_notes(header: dict, out: str) -> list[str]:
    """A PLY header written elsewhere: its comments, obj_info and elements other than the vertices."""
    notes = []
    if out != "ply":
        for key, word in (("comments", "comment"), ("obj_info", "obj_info")):
            lines = header.get(key) or []
            if lines:
                notes.append(f"{len(lines)} PLY {word} line(s) ({'; '.join(repr(c) for c in lines[:3])}"
                             + (", ..." if len(lines) > 3 else "") + ")")
    for element in header.get("elements", []):
        if element.get("name") != "vertex" and element.get("count"):
            notes.append(f"the {element['count']:,} PLY {element['name']} element(s)")
    return notes


def conversion_note(path: str, out_format: str, source_format: str | None, header: dict,
                    mapping: list[tuple[str, str, str]] | None = None) -> str | None:
    """One message naming what writing *header*'s cloud as *out_format* drops and maps, or None.
    *path* is the destination; *source_format* None is guessed from the header's keys; *mapping* a LAS writer's
    (:func:`~cloudsieve.io.las_header.build_header`). The message reads ``"DST: converting FORMAT to OUT drops ...;
    maps ..."``."""
    header = header or {}
    source = _source_family(source_format, header)
    out = "las" if out_format in _LAS else out_format
    if source is None or (source == out and source != "ply"):  # PLY to PLY: its other elements still go
        return None
    dropped = _las_notes(header, out_format) if source == "las" else []
    if source == "ply":
        dropped += _ply_notes(header, out)
    mapped = []
    converted = {name for name, _, how in mapping or [] if how in _HOW}
    for name, las_name, how in mapping or []:
        if how in _HOW:
            mapped.append(f"{name} to LAS {las_name} ({_HOW[how]})")
        elif las_name != name:  # beside a converted copy, or a name LAS does not take as it is
            why = "unchanged" if name in converted else "renamed"
            mapped.append(f"{name} to the extra bytes {las_name!r} ({why})")
    parts = ([f"drops {', '.join(dropped)}"] if dropped else []) + ([f"maps {', '.join(mapped)}"] if mapped else [])
    if not parts:
        return None
    src = (source_format or source).upper()
    return f"{path}: converting {src} to {out_format.upper()} " + "; ".join(parts)
