"""PLY: ASCII and binary (little/big endian) vertices in, binary PLY out.

The reader takes the ``vertex`` element (other elements ignored), any
scalar properties, and needs ``x``, ``y``, ``z``; a binary body is
memory-mapped and sliced, an ASCII body parsed in blocks of lines.

The writer writes binary little-endian PLY: x, y, z as ``float`` when the
source was a binary PLY with float x, y, z (exact), else double; attributes
as vertex properties of their type ((n, k) as ``name_0 .. name_{k-1}``;
64-bit integers as double, with a warning). The vertex count is patched at
the end.
"""

from __future__ import annotations

import itertools
import logging
import os
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..errors import CorruptInputError, InputFormatError
from ..chunk import DEFAULT_CHUNK_SIZE
from ._base import Reader, Writer
from ._text import parse_rows

__all__ = ["PlyReader", "PlyWriter", "read_ply_header"]

logger = logging.getLogger(__name__)

PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_WRITE_TYPES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float", "f8": "double"}
_COUNT_WIDTH = 20


def read_ply_header(path: str) -> dict:
    """Parse the header of the PLY file *path*.
    Returns ``{"format", "version", "comments", "obj_info", "elements": [{"name", "count", "properties": [[name,
    type] or [name, "list", count_type, item_type]]}], "header_size", "header_lines"}``."""
    header: dict[str, Any] = {"comments": [], "obj_info": [], "elements": []}
    with open(path, "rb") as fh:
        first = fh.readline()
        if first.strip() != b"ply":
            shown = first.rstrip(b"\r\n")[:20]
            raise CorruptInputError(f"{path}: not a PLY file (first line {shown!r}, expected 'ply')")
        nlines = 1
        while True:
            raw = fh.readline()
            nlines += 1
            if not raw:
                raise CorruptInputError(f"{path}: PLY header has no end_header line (truncated or corrupt)")
            if len(raw) > 4096 and b"\n" not in raw:  # pragma: no cover - binary junk
                raise CorruptInputError(f"{path}: PLY header line {nlines} is not text")
            line = raw.decode("ascii", errors="replace").strip()
            if not line:
                continue
            word, _, rest = line.partition(" ")
            if word == "format":
                parts = rest.split()
                if not parts or parts[0] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                    raise CorruptInputError(f"{path}, line {nlines}: unknown PLY format {rest!r}")
                header["format"] = parts[0]
                header["version"] = parts[1] if len(parts) > 1 else "1.0"
            elif word == "comment":
                header["comments"].append(rest)
            elif word == "obj_info":
                header["obj_info"].append(rest)
            elif word == "element":
                parts = rest.split()
                try:
                    header["elements"].append({"name": parts[0], "count": int(parts[1]), "properties": []})
                except (IndexError, ValueError):
                    raise CorruptInputError(f"{path}, line {nlines}: bad element line {line!r}") from None
            elif word == "property":
                if not header["elements"]:
                    raise CorruptInputError(f"{path}, line {nlines}: property before any element")
                parts = rest.split()
                if parts and parts[0] == "list" and len(parts) == 4:
                    header["elements"][-1]["properties"].append([parts[3], "list", parts[1], parts[2]])
                elif len(parts) == 2 and parts[0] in PLY_TYPES:
                    header["elements"][-1]["properties"].append([parts[1], parts[0]])
                else:
                    raise CorruptInputError(f"{path}, line {nlines}: bad property line {line!r}")
            elif word == "end_header":
                break
            else:
                raise CorruptInputError(f"{path}, line {nlines}: unexpected PLY header line {line!r}")
        header["header_size"] = fh.tell()
        header["header_lines"] = nlines
    if "format" not in header:
        raise CorruptInputError(f"{path}: PLY header has no format line")
    return header


def _vertex_layout(path: str, header: dict) -> tuple[int, dict, list]:
    """(index of the vertex element, the element, scalar properties)."""
    for i, el in enumerate(header["elements"]):
        if el["name"] == "vertex":
            props = el["properties"]
            names = [p[0] for p in props]
            if not all(c in names for c in ("x", "y", "z")):
                raise InputFormatError(f"{path}: PLY vertex element has no x/y/z properties (found: {', '.join(names) or 'none'})")
            lists = [p[0] for p in props if p[1] == "list"]
            if lists:
                raise InputFormatError(f"{path}: PLY vertex list properties are not supported ({', '.join(lists)})")
            return i, el, props
    raise InputFormatError(
        f"{path}: PLY has no vertex element, so no x/y/z "
        f"(elements: {', '.join(e['name'] for e in header['elements']) or 'none'})"
    )


class PlyReader(Reader):
    """Chunked reader of the vertices of a PLY file (ASCII or binary)."""

    def __init__(self, path: str, format: str, chunk_size: int = DEFAULT_CHUNK_SIZE, **options: Any) -> None:
        super().__init__(path, format, chunk_size, **options)
        header = read_ply_header(path)
        index, element, props = _vertex_layout(path, header)
        self.header = {k: v for k, v in header.items() if k not in ("header_size", "header_lines")}
        self.count = int(element["count"])
        self._props = props
        self._index = index
        self._header_size = header["header_size"]
        self._header_lines = header["header_lines"]
        self._mode = header["format"]
        for name, typ in props:
            if name in ("x", "y", "z"):
                continue
            self.dtypes[name] = (np.dtype(PLY_TYPES[typ]), ())
        if self._mode != "ascii":
            endian = "<" if self._mode == "binary_little_endian" else ">"
            self._dtype = np.dtype([(name, endian + PLY_TYPES[typ]) for name, typ in props])
            offset = self._header_size
            for el in header["elements"][:index]:
                if any(p[1] == "list" for p in el["properties"]):
                    raise InputFormatError(
                        f"{path}: binary PLY element {el['name']!r} with list properties comes before the vertices; "
                        f"not supported"
                    )
                offset += el["count"] * np.dtype([(p[0], endian + PLY_TYPES[p[1]]) for p in el["properties"]]).itemsize
            need = offset + self.count * self._dtype.itemsize
            size = os.path.getsize(path)
            if size < need:
                have = max(size - offset, 0) // self._dtype.itemsize
                raise CorruptInputError(
                    f"{path}: header says {self.count} vertices but the file holds data for only {have} (truncated)"
                )
            self._offset = offset

    def _emit(self, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        n = len(columns["x"])
        xyz = np.empty((n, 3), dtype=np.float64)
        xyz[:, 0], xyz[:, 1], xyz[:, 2] = columns["x"], columns["y"], columns["z"]
        chunk = {"xyz": xyz}
        for name, (dtype, _) in self.dtypes.items():
            if name != "xyz":
                chunk[name] = np.ascontiguousarray(columns[name], dtype=dtype)
        return chunk

    def _read_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Blocks of at most ``chunk_size`` vertices, as dicts."""
        if self.count == 0:
            return
        if self._mode != "ascii":
            body = np.memmap(self.path, dtype=self._dtype, mode="r", offset=self._offset, shape=(self.count,))
            try:
                for start in range(0, self.count, self.chunk_size):
                    block = np.asarray(body[start : start + self.chunk_size])
                    yield self._emit({name: block[name] for name in self._dtype.names})
            finally:
                del body
            return
        yield from self._ascii_chunks()

    def _ascii_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        ncols = len(self._props)
        names = [p[0] for p in self._props]
        with open(self.path, "rb") as fh:
            fh.seek(self._header_size)
            lineno = self._header_lines
            text = (raw.decode("ascii", errors="replace") for raw in fh)
            # skip the rows of elements before the vertices
            skip = sum(el["count"] for el in read_ply_header(self.path)["elements"][: self._index])
            for _ in itertools.islice(text, skip):
                lineno += 1
            left = self.count
            while left:
                want = min(self.chunk_size, left)
                block = []
                for line in itertools.islice(text, want):
                    lineno += 1
                    block.append((lineno, line))
                if len(block) < want:
                    got = self.count - left + len(block)
                    raise CorruptInputError(
                        f"{self.path}: header says {self.count} vertices but the file holds only {got} rows (truncated)"
                    )
                values = parse_rows(block, ncols, self.path)
                left -= len(block)
                yield self._emit({name: values[:, i] for i, name in enumerate(names)})


def _source_xyz_code(header: dict) -> str:
    """"f4" when *header* is a binary PLY header whose vertex x, y, z are all ``float``/``float32``, else "f8"."""
    if not str(header.get("format", "")).startswith("binary"):
        return "f8"
    for element in header.get("elements") or []:
        if isinstance(element, dict) and element.get("name") == "vertex":
            types = {p[0]: p[1] for p in element.get("properties", []) if len(p) == 2}
            if all(PLY_TYPES.get(types.get(axis)) == "f4" for axis in "xyz"):
                return "f4"
    return "f8"


class PlyWriter(Writer):
    """Binary little-endian PLY writer, streamed in chunks."""

    def _open(self) -> None:
        code = _source_xyz_code(self.header) if self.source_format in (None, "ply") else "f8"
        fields: list[tuple[str, str, str, int | None]] = [("x", code, "xyz", 0), ("y", code, "xyz", 1),
                                                          ("z", code, "xyz", 2)]
        widened = []
        for name, (dtype, shape) in self.dtypes.items():
            if name == "xyz":
                continue
            code = dtype.str.lstrip("<>|=")
            if dtype.kind == "b":
                code = "u1"
            if code not in _WRITE_TYPES:
                if dtype.kind in "uif":
                    widened.append(name)
                    code = "f8"
                else:
                    logger.warning("%s: attribute %r of type %s has no PLY type; not written", self.path, name, dtype)
                    continue
            if shape == ():
                fields.append((name, code, name, None))
            elif len(shape) == 1:
                fields.extend((f"{name}_{i}", code, name, i) for i in range(shape[0]))
            else:
                logger.warning("%s: attribute %r of shape %s not written to PLY", self.path, name, shape)
        if widened:
            logger.warning("%s: PLY has no 64-bit integer type; wrote %s as double", self.path, ", ".join(widened))
        self._fields = fields
        self._dtype = np.dtype([(f[0], "<" + f[1]) for f in fields])
        lines = ["ply", "format binary_little_endian 1.0", "comment written by cloudsieve"]
        if self.source_format:
            lines.append(f"comment source format {self.source_format}")
        if self.source_format == "ply":  # the source's comments and obj_info are kept
            lines.extend(f"{key} {text}".encode("ascii", "replace").decode() for key, field in
                         (("comment", "comments"), ("obj_info", "obj_info")) for text in self.header.get(field, []))
        self._count_line = len("\n".join(lines)) + 1
        lines.append("element vertex " + "0".ljust(_COUNT_WIDTH))
        lines.extend(f"property {_WRITE_TYPES[f[1]]} {f[0]}" for f in fields)
        lines.append("end_header")
        self.file.write(("\n".join(lines) + "\n").encode("ascii"))

    def _write(self, chunk: dict[str, np.ndarray]) -> None:
        n = len(chunk["xyz"])
        out = np.empty(n, dtype=self._dtype)
        for name, _code, source, col in self._fields:
            values = chunk[source]
            out[name] = values if col is None else values[:, col]
        self.file.write(out.tobytes())

    def _close(self) -> None:
        self.file.seek(self._count_line + len("element vertex "))
        self.file.write(str(self.count).ljust(_COUNT_WIDTH).encode("ascii"))
