"""SRC as one cloud of many files: :func:`expand_sources` (README, "Usage").

A glob (sorted by path), a directory or prefix that is not a store (its
LAS/LAZ files, sorted), a list file (``.lst``, or a ``.txt`` whose first line
names a cloud file; one path per line, relative to the list), a VPC (its
order), else SRC itself. Any may be a URL. The order numbers the points,
which fixes the result for a seed.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from .. import storage
from ..errors import EmptyInputError, InputFormatError, InputIsDirectoryError, InputNotFoundError

__all__ = ["expand_sources", "remembered", "is_many", "LIST_EXTENSIONS", "TILE_EXTENSIONS"]

_remembered: dict[str, list[str]] | None = None  # SRC -> its files, inside :func:`remembered`

#: extensions of the files a directory source contributes
TILE_EXTENSIONS = (".las", ".laz")
#: extensions always read as a list of paths
LIST_EXTENSIONS = (".lst",)
_GLOB_CHARS = "*?["


def _is_glob(src: str) -> bool:
    return any(c in src for c in _GLOB_CHARS) and not storage.exists(src)


def _first_line_names_a_cloud(src: str) -> bool:
    """True when the first non-blank, non-comment line of the text file *src* names an existing cloud file."""
    with storage.open_input(src) as fh:
        head = fh.read(4096).decode("utf-8", errors="replace")
    for line in head.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        return line.lower().endswith(TILE_EXTENSIONS + (".ply", ".e57")) and storage.isfile(_resolve(src, line))
    return False


def _is_list_file(src: str) -> bool:
    low = src.lower()
    if low.endswith(LIST_EXTENSIONS):
        return True
    return low.endswith(".txt") and storage.isfile(src) and _first_line_names_a_cloud(src)


def _is_directory_source(src: str) -> bool:
    """A folder (or, for a URL, a prefix) that is not a point store."""
    return storage.isdir(src) and not storage.exists(storage.join(src, "zarr.json"))


def is_many(src: str | os.PathLike) -> bool:
    """True when *src* names several files (a glob, a directory, a list file or a VPC), not one file or a store."""
    src = os.fspath(src)
    return (_is_glob(src) or _is_directory_source(src) or src.lower().endswith(".vpc") or _is_list_file(src))


def _resolve(list_file: str, line: str) -> str:
    """A list's *line*: a URL or an absolute path as it is, else relative to the list's folder (or prefix)."""
    return storage.join(storage.parent(list_file), line)


def _absolute(path: str) -> str:
    return path if storage.is_url(path) else os.path.abspath(path)


def _read_list(src: str) -> list[str]:
    out = []
    with storage.open_input(src) as fh:
        data = fh.read()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputFormatError(f"{src}: not a list of files (not UTF-8 text)") from None
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        path = _resolve(src, line)
        if not storage.isfile(path):
            raise InputNotFoundError(f"{src}, line {number}: {line}: no such file")
        out.append(_absolute(path))
    return out


def expand_sources(src: str | os.PathLike) -> list[str]:
    """The files that make the cloud *src*, in order, absolute; ``[src]`` for one file or a store.
    Raises EmptyInputError (a glob, list or VPC naming no file), InputIsDirectoryError (a directory with no
    LAS/LAZ), InputNotFoundError (a listed file is missing), InputFormatError (a bad VPC or list)."""
    src = os.fspath(src)
    if _remembered is not None:
        if src not in _remembered:
            _remembered[src] = _expand(src)
        return list(_remembered[src])
    return _expand(src)


@contextlib.contextmanager
def remembered() -> Iterator[None]:
    """Within the block, each SRC is expanded once: checks, identity and ingest see the same listing, at one cost."""
    global _remembered
    saved = _remembered
    _remembered = {} if saved is None else saved
    try:
        yield
    finally:
        _remembered = saved


def _expand(src: str) -> list[str]:
    if _is_glob(src):
        files = storage.glob(src)
        what = f"{src}: the pattern matches no file"
    elif _is_directory_source(src):
        files = [storage.join(src, n) for n in storage.listdir(src) if n.lower().endswith(TILE_EXTENSIONS)]
        if not files:
            raise InputIsDirectoryError(f"{src} is a directory, not a point cloud file or point store, and holds "
                                        f"no LAS/LAZ file to read as one cloud")
        what = ""
    elif src.lower().endswith(".vpc"):
        from .vpc import read_vpc

        files = read_vpc(src)
        what = f"{src}: the VPC lists no file"
    elif _is_list_file(src):
        files = _read_list(src)
        what = f"{src}: the list names no file"
    else:
        return [src]
    if not files:
        raise EmptyInputError(what)
    return [_absolute(p) for p in files]
