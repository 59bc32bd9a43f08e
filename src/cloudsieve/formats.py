"""The point cloud formats by name: extensions, reader and writer, as a table (a leaf: imports nothing).

:mod:`cloudsieve.io` registers each row; :mod:`cloudsieve.params` reads the format names without importing io.
"""

from __future__ import annotations

__all__ = ["FORMAT_TABLE", "READABLE", "WRITABLE"]

#: name -> (extensions, reader "module:Class" or None, writer "module:Class" or None)
FORMAT_TABLE: dict[str, tuple[tuple[str, ...], str | None, str | None]] = {
    "las": ((".las",), "cloudsieve.io.las:LasReader", "cloudsieve.io.las:LasWriter"),
    "laz": ((".laz",), "cloudsieve.io.las:LasReader", "cloudsieve.io.las:LasWriter"),
    "copc": ((".copc.laz",), "cloudsieve.io.las:LasReader", None),
    "ply": ((".ply",), "cloudsieve.io.ply:PlyReader", "cloudsieve.io.ply:PlyWriter"),
    "e57": ((".e57",), "cloudsieve.io.e57:E57Reader", None),
    "xyz": ((".xyz", ".txt", ".csv", ".pts"), "cloudsieve.io.xyz:XyzReader", "cloudsieve.io.xyz:XyzWriter"),
}
#: the formats cloudsieve reads / writes (COPC is written from a point store, by cloudsieve.store.copc)
READABLE = tuple(name for name, (_, reader, _) in FORMAT_TABLE.items() if reader is not None)
WRITABLE = tuple(name for name, (_, _, writer) in FORMAT_TABLE.items() if writer is not None or name == "copc")
