"""Where a LAS/LAZ/COPC file keeps its parts, read without decoding a point: header, LASzip VLR, chunk table.

Used by the readers and by the LAS export's splice (:mod:`cloudsieve.store.export_las`).
"""

from __future__ import annotations

from .. import storage

__all__ = ["read_header", "laszip_vlr", "chunk_table"]


def read_header(path: str):
    """The ``laspy.LasHeader`` of the LAS/LAZ/COPC file *path* (a path or a URL), its EVLRs included."""
    import laspy

    with laspy.open(storage.open_input(path, storage.HEADER_BLOCK), closefd=True) as reader:
        return reader.header


def laszip_vlr(header):
    """The ``lazrs.LazVlr`` of the LASzip VLR of *header*, or None (the points are not compressed)."""
    vlr = next((v for v in header.vlrs if type(v).__name__ == "LasZipVlr"), None)
    if vlr is None:
        return None
    import lazrs

    return lazrs.LazVlr(vlr.record_data)


def chunk_table(fh, start: int, vlr) -> list[tuple[int, int]]:
    """The chunk table of the LAZ file *fh* whose points start at byte *start*: (points, bytes) per chunk."""
    import lazrs

    fh.seek(start)
    return lazrs.read_chunk_table(fh, vlr)
