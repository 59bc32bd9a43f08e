"""Point cloud file formats: streaming readers and writers picked by extension.

Each format module exposes a :class:`~cloudsieve.io._base.Reader` and/or a
:class:`~cloudsieve.io._base.Writer` subclass and is registered here with
:func:`register_format` (as in meshio). Modules are imported lazily, so an
optional dependency (pye57 for E57) is needed only when its format is used.

============  ====================================  ======  ======
format        extensions                            read    write
============  ====================================  ======  ======
las           .las                                  yes     yes
laz           .laz                                  yes     yes
copc          .copc.laz                             yes     no (write .laz)
ply           .ply                                  yes     yes (binary LE)
e57           .e57                                  yes     no
xyz           .xyz .txt .csv .pts                   yes     yes
============  ====================================  ======  ======

Example
-------
>>> from cloudsieve.io import open_reader
>>> with open_reader("scan.laz", chunk_size=500_000) as reader:  # doctest: +SKIP
...     for start, arrays in reader.chunks():  # cloudsieve.store.Chunk
...         xyz = arrays["xyz"]          # (n, 3) float64, points start .. start + n - 1
...         intensity = arrays["intensity"]
"""

from __future__ import annotations

import importlib
import os
from typing import Any

import numpy as np

from ..errors import (
    EmptyInputError,
    InputIsDirectoryError,
    InputNotFoundError,
    InvalidParameterError,
    UnknownFormatError,
)
from ..store.pointstore import DEFAULT_CHUNK_SIZE
from ._base import Reader, Writer

__all__ = [
    "Reader",
    "Writer",
    "register_format",
    "detect_format",
    "open_reader",
    "open_writer",
    "read_cloud",
    "FORMATS",
]

#: format name -> {"extensions": [...], "reader": "module:Class" | None, "writer": ... | None}
FORMATS: dict[str, dict[str, Any]] = {}
_EXTENSIONS: dict[str, str] = {}


def register_format(name: str, extensions: list[str], reader: Any = None, writer: Any = None) -> None:
    """Register a format: its extensions and its reader/writer classes.

    Parameters
    ----------
    name : str
        Format name ("las", ...).
    extensions : list of str
        Suffixes including the dot, lower case (".copc.laz" is allowed).
    reader, writer : class or "module:Class" string, optional
        Classes following :class:`Reader` / :class:`Writer`; strings are
        imported on first use.
    """
    FORMATS[name] = {"extensions": list(extensions), "reader": reader, "writer": writer}
    for ext in extensions:
        _EXTENSIONS[ext.lower()] = name


def _resolve(spec: Any) -> Any:
    if isinstance(spec, str):
        module, _, attr = spec.partition(":")
        return getattr(importlib.import_module(module), attr)
    return spec


register_format("las", [".las"], "cloudsieve.io.las:LasReader", "cloudsieve.io.las:LasWriter")
register_format("laz", [".laz"], "cloudsieve.io.las:LasReader", "cloudsieve.io.las:LasWriter")
register_format("copc", [".copc.laz"], "cloudsieve.io.las:LasReader", None)
register_format("ply", [".ply"], "cloudsieve.io.ply:PlyReader", "cloudsieve.io.ply:PlyWriter")
register_format("e57", [".e57"], "cloudsieve.io.e57:E57Reader", None)
register_format("xyz", [".xyz", ".txt", ".csv", ".pts"], "cloudsieve.io.xyz:XyzReader", "cloudsieve.io.xyz:XyzWriter")


def detect_format(path: str | os.PathLike, format: str | None = None) -> str:
    """The format of *path*: *format* if given, else by extension.

    ``.copc.laz`` is "copc"; ``.txt``, ``.csv``, ``.xyz``, ``.pts`` are "xyz".

    Raises
    ------
    UnknownFormatError
        Unknown *format* or extension.
    """
    path = os.fspath(path)
    if format is not None:
        fmt = format.lower().lstrip(".")
        if fmt not in FORMATS:
            raise UnknownFormatError(f"{path}: unknown format {format!r}; known formats: {', '.join(FORMATS)}")
        return fmt
    name = os.path.basename(path.rstrip("/")).lower()
    for ext in sorted(_EXTENSIONS, key=len, reverse=True):
        if name.endswith(ext):
            return _EXTENSIONS[ext]
    ext = os.path.splitext(name)[1] or "(none)"
    raise UnknownFormatError(
        f"{path}: unknown point cloud format (extension {ext}); known extensions: "
        f"{', '.join(sorted(_EXTENSIONS))}; give the format explicitly (--format)"
    )


def check_input_file(path: str) -> None:
    """Raise the matching error when *path* is missing, a folder or empty."""
    if not os.path.exists(path):
        raise InputNotFoundError(f"{path}: no such file")
    if os.path.isdir(path):
        raise InputIsDirectoryError(f"{path} is a directory, not a point cloud file")
    if os.path.getsize(path) == 0:
        raise EmptyInputError(f"{path} is empty (0 bytes)")


def open_reader(
    path: str | os.PathLike, *, format: str | None = None, chunk_size: int = DEFAULT_CHUNK_SIZE, **options: Any
) -> Reader:
    """Open *path* for streaming reading.

    Parameters
    ----------
    path : str or path-like
        A LAS/LAZ/COPC/PLY/E57/XYZ file.
    format : str, optional
        Overrides the format found from the extension.
    chunk_size : int
        Points per chunk.
    **options
        Format-specific options (XYZ: ``delimiter``, ``columns``, ``skiprows``).

    Returns
    -------
    Reader
        A context manager; iterate ``reader.chunks()``.

    Raises
    ------
    InputNotFoundError, InputIsDirectoryError, EmptyInputError,
    UnknownFormatError, CorruptInputError, InputFormatError
    InvalidParameterError
        *chunk_size* is not positive.
    """
    path = os.fspath(path)
    if int(chunk_size) <= 0:
        raise InvalidParameterError(f"chunk_size must be positive, got {chunk_size}")
    check_input_file(path)
    fmt = detect_format(path, format)
    spec = FORMATS[fmt]["reader"]
    if spec is None:  # pragma: no cover - every format reads
        raise UnknownFormatError(f"{path}: reading {fmt} is not supported")
    return _resolve(spec)(path, fmt, chunk_size=int(chunk_size), **options)


def open_writer(
    path: str | os.PathLike,
    *,
    header: dict,
    dtypes: dict,
    format: str | None = None,
    source_format: str | None = None,
    overwrite: bool = False,
    **options: Any,
) -> Writer:
    """Open *path* for chunked writing (to a temporary name, renamed on success).

    Parameters
    ----------
    path : str or path-like
        Destination file.
    header : dict
        Source header (``Reader.header`` / ``PointStore.header``).
    dtypes : dict
        Attribute name -> (dtype, per-point shape), "xyz" included.
    format : str, optional
        Overrides the format found from the extension.
    source_format : str, optional
        Format *header* came from; a LAS header is carried over to LAS/LAZ.
    overwrite : bool
        Replace an existing destination.
    **options
        ``bounds`` ((2, 3) array, lets the LAS writer choose scales/offsets
        for non-LAS sources).

    Raises
    ------
    UnknownFormatError, DestinationExistsError, DestinationNotWritableError
    """
    path = os.fspath(path)
    fmt = detect_format(path, format)
    spec = FORMATS[fmt]["writer"]
    if spec is None:
        hint = " (write .laz: a COPC file needs an octree order)" if fmt == "copc" else ""
        raise UnknownFormatError(f"{path}: writing {fmt} files is not supported{hint}")
    return _resolve(spec)(
        path, header=header, dtypes=dtypes, format=fmt, source_format=source_format, overwrite=overwrite, **options
    )


def read_cloud(path: str | os.PathLike, *, format: str | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Load a whole (small) cloud: a point store (see :func:`cloudsieve.store.is_store`), else a file.

    This loads everything into memory: use it for tests, tiles and small
    clouds; stream large ones with :func:`open_reader`.

    Returns
    -------
    xyz : ndarray of shape (n, 3), float64
    attributes : dict of str to ndarray of shape (n,) or (n, k)
    """
    path = os.fspath(path)
    from ..store import PointStore, is_store

    if is_store(path):
        store = PointStore.open(path)
        parts = [arrays for _, arrays in store.chunks()]
        dtypes = store.dtypes
    else:
        with open_reader(path, format=format) as reader:
            parts = [arrays for _, arrays in reader.chunks()]
            dtypes = reader.dtypes
    out = {}
    for name, (dtype, shape) in dtypes.items():
        if parts:
            out[name] = np.concatenate([p[name] for p in parts])
        else:
            out[name] = np.empty((0, *shape), dtype=dtype)
    xyz = out.pop("xyz")
    return xyz, out
