"""Point cloud file formats: streaming readers and writers picked by extension.

Each format module has a :class:`~cloudsieve.io._base.Reader` and/or
:class:`~cloudsieve.io._base.Writer` subclass, registered here with
:func:`register_format` and imported lazily (pye57 is needed only for E57).

============  ====================================  ======  ======
format        extensions                            read    write
============  ====================================  ======  ======
las           .las                                  yes     yes
laz           .laz                                  yes     yes
copc          .copc.laz                             yes     from a store (:mod:`cloudsieve.store.copc`)
ply           .ply                                  yes     yes (binary LE)
e57           .e57                                  yes     no
xyz           .xyz .txt .csv .pts                   yes     yes
============  ====================================  ======  ======

>>> from cloudsieve.io import open_reader
>>> with open_reader("scan.laz", chunk_size=500_000) as reader:  # doctest: +SKIP
...     for start, arrays in reader.chunks():  # cloudsieve.store.Chunk
...         xyz = arrays["xyz"]          # (n, 3) float64, points start .. start + n - 1
"""

from __future__ import annotations

import importlib
import os
from typing import Any

import numpy as np

from .. import storage
from ..errors import (
    DestinationNotWritableError,
    EmptyInputError,
    InputIsDirectoryError,
    InputNotFoundError,
    InputNotReadableError,
    UnknownFormatError,
)
from ..chunk import DEFAULT_CHUNK_SIZE
from ..formats import FORMAT_TABLE
from ..params import check
from ..paths import local_path, store_group
from ..atomic import check_destination
from ._base import Reader, Writer

__all__ = [
    "Reader",
    "Writer",
    "register_format",
    "detect_format",
    "check_readable",
    "check_writable",
    "check_folder",
    "open_reader",
    "open_writer",
    "read_cloud",
    "FORMATS",
]

#: format name -> {"extensions": [...], "reader": "module:Class" | None, "writer": ... | None}
FORMATS: dict[str, dict[str, Any]] = {}
_EXTENSIONS: dict[str, str] = {}


def register_format(name: str, extensions: list[str], reader: Any = None, writer: Any = None) -> None:
    """Register format *name*: its lower-case *extensions* (with the dot) and its reader/writer.
    *reader* and *writer* are :class:`Reader` / :class:`Writer` subclasses or ``"module:Class"`` strings imported
    on first use."""
    FORMATS[name] = {"extensions": list(extensions), "reader": reader, "writer": writer}
    for ext in extensions:
        _EXTENSIONS[ext.lower()] = name


def _resolve(spec: Any) -> Any:
    if isinstance(spec, str):
        module, _, attr = spec.partition(":")
        return getattr(importlib.import_module(module), attr)
    return spec


for _name, (_extensions, _reader, _writer) in FORMAT_TABLE.items():  # the table params.py reads too
    register_format(_name, list(_extensions), _reader, _writer)


def detect_format(path: str | os.PathLike, format: str | None = None) -> str:
    """The format of *path*: *format* if given, else by extension; UnknownFormatError otherwise."""
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
    """Raise the matching error when *path* is missing, a folder or empty (a URL: a missing object or bucket,
    a prefix, an empty object, access denied, an unreachable store)."""
    if storage.is_url(path):
        fs, p = storage.filesystem(path)
        with storage.remote_errors(path):
            info = fs.info(p)
        if info.get("type") == "directory":
            raise InputIsDirectoryError(f"{path} is a prefix (a folder), not a point cloud file")
        if not info.get("size"):
            raise EmptyInputError(f"{path} is empty (0 bytes)")
        return
    if not os.path.exists(path):
        raise InputNotFoundError(f"{path}: no such file")
    if os.path.isdir(path):
        raise InputIsDirectoryError(f"{path} is a directory, not a point cloud file")
    if os.path.getsize(path) == 0:
        raise EmptyInputError(f"{path} is empty (0 bytes)")


def check_readable(path: str | os.PathLike, format: str | None = None) -> None:
    """Raise unless *path* is a point cloud file cloudsieve can read, or a point store.
    Checks what is known without reading points: exists, is a non-empty file, opens, and its format has a reader. A
    folder must be a point store; a URL is a store or a file. Raises InputNotFoundError, InputIsDirectoryError,
    EmptyInputError, InputNotReadableError, UnknownFormatError or StoreNotFoundError."""
    path = os.fspath(path)
    local = local_path(path)
    if local is None:  # a URL: a point store (a zarr.json at its root), else a file
        if storage.exists(storage.join(path, "zarr.json")):
            store_group(path, "r")
            return
        check_input_file(path)
    elif os.path.isdir(local):
        if not os.path.exists(os.path.join(local, "zarr.json")):
            raise InputIsDirectoryError(f"{path} is a directory, not a point cloud file or point store")
        store_group(path, "r")  # what PointStore.open accepts
        return
    else:
        check_input_file(path)
        try:
            with open(local, "rb"):
                pass
        except OSError as exc:
            raise InputNotReadableError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    spec = FORMATS[detect_format(path, format)]["reader"]
    if spec is None:  # pragma: no cover - every format reads
        raise UnknownFormatError(f"{path}: reading {format} is not supported")


def _writable_formats() -> str:
    return ", ".join(f"{name} ({' '.join(f['extensions'])})" for name, f in FORMATS.items()
                     if f["writer"] is not None or name == "copc")


def check_writable(path: str | os.PathLike, format: str | None = None, *, overwrite: bool = False) -> str:
    """Raise unless a cloud of *format* (default: by extension) can be written at *path*; returns the format.
    Creates nothing. UnknownFormatError (listing the writable formats) for a format without a writer (E57, COPC);
    for a local path, DestinationExistsError unless *overwrite*, DestinationNotWritableError when its folder is
    missing or not writable."""
    path = os.fspath(path)
    try:
        fmt = detect_format(path, format)
    except UnknownFormatError:
        ext = os.path.splitext(os.path.basename(path.rstrip("/")))[1] or "(none)"
        what = f"format {format!r}" if format is not None else f"extension {ext}"
        raise UnknownFormatError(
            f"{path}: cannot write {what} (unknown format); formats that can be written: {_writable_formats()}"
        ) from None
    if FORMATS[fmt]["writer"] is None and fmt != "copc":  # COPC: written from a store (cloudsieve.store.copc)
        raise UnknownFormatError(
            f"{path}: writing {fmt} files is not supported; formats that can be written: {_writable_formats()}")
    if local_path(path) is None:  # a URL: the bucket must exist; an object there only with overwrite
        check_destination(path, overwrite)
        return fmt
    check_destination(path, overwrite)
    parent = os.path.dirname(os.path.abspath(path))
    if not os.access(parent, os.W_OK | os.X_OK):
        raise DestinationNotWritableError(f"cannot write {path}: folder {parent} is not writable")
    return fmt


def check_folder(path: str | os.PathLike) -> None:
    """Raise DestinationNotWritableError unless the folder *path* exists and is writable, or could be created.
    Nothing is created; a remote URL is not checked."""
    path = os.fspath(path)
    if "://" in path and not path.startswith("file://"):
        return
    existing = local_path(path)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise DestinationNotWritableError(f"cannot write {path}: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise DestinationNotWritableError(f"cannot write {path}: folder {existing} is not writable")


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
    check("chunk_size", chunk_size)  # the option's one check (params)
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
    """Load a whole (small) cloud file into memory: ``(xyz (n, 3) float64, attributes)``.
    Stream large ones with :func:`open_reader`; a point store: :func:`cloudsieve.store.read_cloud`."""
    with open_reader(path, format=format) as reader:
        return concatenated([arrays for _, arrays in reader.chunks()], reader.dtypes)


def concatenated(parts: list[dict[str, np.ndarray]], dtypes: dict) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The chunks *parts* of a cloud with attributes *dtypes* as one cloud ``(xyz, attributes)``."""
    out = {}
    for name, (dtype, shape) in dtypes.items():
        if parts:
            out[name] = np.concatenate([p[name] for p in parts])
        else:
            out[name] = np.empty((0, *shape), dtype=dtype)
    xyz = out.pop("xyz")
    return xyz, out
