"""Where clouds and stores live: local paths and fsspec URLs (``file:///...`` is the local path it names).

A leaf (imports :mod:`cloudsieve.errors`, :mod:`cloudsieve.storage`, :mod:`cloudsieve.handles`).
:func:`store_group` is the one test of whether a point store is at a path.
"""

from __future__ import annotations

import functools
import os
import posixpath
from typing import TYPE_CHECKING

from . import handles, storage
from .errors import CloudsieveError, SameSourceDestinationError, StoreNotFoundError
from .storage import local as local_path

__all__ = ["local_path", "same_path", "holds", "refuse_source", "store_foreign", "zarr_store", "delete_store", "STORE_ATTR", "store_group", "is_store"]

STORE_ATTR = "cloudsieve"

if TYPE_CHECKING:
    import zarr


#: protocols fsspec gives the same filesystem under two names
_ALIASES = {"s3a": "s3", "gcs": "gs", "abfs": "az"}


def _canonical(url: str) -> str:
    """*url* as URLs are compared: the protocol's one name, the path normalised (``b//in/./a.laz`` is
    ``b/in/a.laz``, no trailing "/"), as some stores read keys; on the safe side."""
    proto, _, rest = url.partition("://")
    proto = proto.lower()
    return f"{_ALIASES.get(proto, proto)}://{posixpath.normpath(rest) if rest else ''}"


def same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when *a* and *b* name the same file or folder (symlinks resolved; URLs compared by
    :func:`_canonical` form)."""
    a, b = os.fspath(a), os.fspath(b)
    la, lb = local_path(a), local_path(b)
    if la is None or lb is None:
        return la is None and lb is None and _canonical(a) == _canonical(b)
    return os.path.realpath(la) == os.path.realpath(lb)


def holds(folder: str | os.PathLike, path: str | os.PathLike) -> bool:
    """True when *path* is *folder* or lies inside it (symlinks resolved; URLs compared by :func:`_canonical`
    form), so that replacing or deleting *folder* would remove *path*."""
    folder, path = os.fspath(folder), os.fspath(path)
    lf, lp = local_path(folder), local_path(path)
    if lf is None or lp is None:
        if (lf is None) != (lp is None):
            return False
        f, p = _canonical(folder), _canonical(path)
        return p == f or p.startswith(f.rstrip("/") + "/")
    f, p = os.path.realpath(lf), os.path.realpath(lp)
    return os.path.commonpath([f, p]) == f


def refuse_source(source: str, dst: str) -> None:
    """Refuse *dst* when it is *source* or a folder holding it (SameSourceDestinationError): writing it would
    replace the input."""
    if same_path(source, dst):
        raise SameSourceDestinationError(f"destination {dst} is the source {source}: cloudsieve never overwrites its input")
    if holds(dst, source):
        raise SameSourceDestinationError(
            f"destination {dst} holds the source {source}: cloudsieve never overwrites its input")


def store_foreign(path: str | os.PathLike) -> str | None:
    """None when the local folder (or URL prefix) *path* is empty or absent, or a cloudsieve point store
    (complete or not: a zarr group whose attributes hold "cloudsieve"), else what it holds instead, for a
    message; read from its ``zarr.json`` alone (no zarr import)."""
    import json

    path = os.fspath(path)
    if storage.is_url(path):
        names = storage.listdir(path, files_only=False) if storage.isdir(path) else []
    else:
        names = sorted(os.listdir(path))
    if not names:
        return None
    try:
        with storage.open_input(storage.join(path, "zarr.json"), storage.HEADER_BLOCK) as fh:
            attrs = json.load(fh).get("attributes", {})
        if isinstance(attrs, dict) and STORE_ATTR in attrs:
            return None
    except (CloudsieveError, OSError, ValueError, AttributeError):
        pass
    return f"{len(names)} entr{'y' if len(names) == 1 else 'ies'} ({names[0]}{', ...' if len(names) > 1 else ''}) and no cloudsieve point store"


def zarr_store(path: str, read_only: bool):
    """A zarr store object for a local path or an fsspec URL."""
    import zarr  # here: importing this module (io does) loads no zarr

    local = local_path(path)
    if local is not None:
        return zarr.storage.LocalStore(local, read_only=read_only)
    import warnings

    # some object stores list a deleted group's prefix for a while: zarr warns of no node, which is the answer
    warnings.filterwarnings("ignore", message=r"Object at .* is not recognized as a component of a Zarr hierarchy")
    options = storage.fs_options(path)
    if storage.protocol(path) in ("s3", "s3a"):
    # zarr reads whole objects: one GET each, not s3fs's HEAD for the size first
        options.setdefault("max_concurrency", 1)
    # in a stage's task: a store that reads each shard's index once (handles.py)
    return handles.remote_store(lambda: _mapped(zarr.storage.FsspecStore.from_url(
        path, read_only=read_only, storage_options=options), path))


def _mapped(store, path: str):
    """The zarr *store* of the URL *path*, its reads' and writes' errors cloudsieve's (one line naming *path*,
    :func:`cloudsieve.storage.remote_errors`), as the errors of every other request of a run."""
    store.__class__ = _mapped_store_class(type(store))
    object.__setattr__(store, "_url", path)
    return store


@functools.cache
def _mapped_store_class(base: type) -> type:
    class MappedStore(base):  # type: ignore[valid-type, misc]
        async def get(self, *args, **kwargs):
            with storage.remote_errors(self._url):
                return await super().get(*args, **kwargs)

        async def get_partial_values(self, *args, **kwargs):
            with storage.remote_errors(self._url):
                return await super().get_partial_values(*args, **kwargs)

        async def exists(self, *args, **kwargs):
            with storage.remote_errors(self._url):
                return await super().exists(*args, **kwargs)

        async def set(self, *args, **kwargs):
            with storage.remote_errors(self._url, writing=True):
                return await super().set(*args, **kwargs)

        async def delete(self, *args, **kwargs):
            with storage.remote_errors(self._url, writing=True):
                return await super().delete(*args, **kwargs)

    return MappedStore


def delete_store(path: str | os.PathLike) -> None:
    """Delete the store (or any folder) at *path*, local or remote; a missing path is ignored."""
    storage.remove(os.fspath(path), recursive=True)


def store_group(path: str | os.PathLike, mode: str = "r") -> tuple[zarr.Group, dict]:
    """The zarr group of the complete point store at *path* and its "cloudsieve" attributes.
    *mode* "r" opens read-only, else read-write. StoreNotFoundError when *path* is missing or not a complete point
    store."""
    path = os.fspath(path)
    # a URL: opening the group finds out (a prefix's existence would take a listing)
    if not storage.is_url(path) and not storage.exists(path):
        raise StoreNotFoundError(f"{path}: no such point store")
    local = local_path(path)
    if local is not None and os.path.isfile(local):
        raise StoreNotFoundError(f"{path} is a file, not a point store (ingest it first: cloudsieve ingest)")
    import zarr

    with storage.remote_errors(path):  # access denied, an unreachable store: one line
        try:
            group = zarr.open_group(zarr_store(path, read_only=(mode == "r")), mode="r" if mode == "r" else "r+",
                                    zarr_format=3, use_consolidated=False)  # no probing for v2 or consolidated keys
        except FileNotFoundError as exc:
            if storage.is_url(path):
                raise StoreNotFoundError(f"{path}: no such point store") from exc
            raise StoreNotFoundError(f"{path} is not a cloudsieve point store: {exc}") from exc
        except (KeyError, ValueError, zarr.errors.NodeTypeValidationError) as exc:  # type: ignore[attr-defined]
            raise StoreNotFoundError(f"{path} is not a cloudsieve point store: {exc}") from exc
    meta = group.attrs.get(STORE_ATTR)
    if not isinstance(meta, dict) or not meta.get("complete", False):
        raise StoreNotFoundError(f"{path} is not a complete cloudsieve point store (no 'cloudsieve' attributes)")
    return group, meta


def is_store(path: str | os.PathLike) -> bool:
    """True when *path* (local path or fsspec URL) holds a complete point store (:func:`store_group` accepts it)."""
    try:
        store_group(path)
    except (CloudsieveError, OSError, ValueError):
        return False
    return True
