"""Where a store lives: local paths and fsspec URLs (``file:///...`` is the local path it names)."""

from __future__ import annotations

import os
import shutil
from urllib.parse import unquote, urlparse

import zarr

__all__ = ["local_path", "same_path", "path_exists", "zarr_store", "delete_store"]


def local_path(path: str | os.PathLike) -> str | None:
    """The local file-system path behind *path*, or None for a remote URL.

    ``file:///a/b`` and plain paths are local; ``s3://...``, ``memory://...``
    and other fsspec URLs are not.
    """
    path = os.fspath(path)
    if "://" not in path:
        return os.path.abspath(path)
    url = urlparse(path)
    if url.scheme == "file":
        return os.path.abspath(unquote(url.netloc + url.path))
    return None


def same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when *a* and *b* name the same file or folder (symlinks resolved; URLs compared as text)."""
    a, b = os.fspath(a), os.fspath(b)
    la, lb = local_path(a), local_path(b)
    if la is None or lb is None:
        return a.rstrip("/") == b.rstrip("/")
    return os.path.realpath(la) == os.path.realpath(lb)


def zarr_store(path: str, read_only: bool):
    """A zarr store object for a local path or an fsspec URL."""
    local = local_path(path)
    if local is not None:
        return zarr.storage.LocalStore(local, read_only=read_only)
    return zarr.storage.FsspecStore.from_url(path, read_only=read_only)


def path_exists(path: str) -> bool:
    """True when something (file or folder) is at *path*, a local path or an fsspec URL."""
    local = local_path(path)
    if local is not None:
        return os.path.exists(local)
    import fsspec

    fs, p = fsspec.core.url_to_fs(path)
    return fs.exists(p)


def delete_store(path: str | os.PathLike) -> None:
    """Delete the store (or any folder) at *path*, local or remote; a missing path is ignored."""
    path = os.fspath(path)
    local = local_path(path)
    if local is not None:
        shutil.rmtree(local, ignore_errors=True)
    else:  # pragma: no cover - remote stores
        import fsspec

        fs, p = fsspec.core.url_to_fs(path)
        if fs.exists(p):
            fs.rm(p, recursive=True)
