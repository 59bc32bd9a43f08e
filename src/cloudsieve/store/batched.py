"""Arrays created on object storage in one batch of writes (the driver's requests do not grow with the arrays).

zarr creating an array on an fsspec store checks that nothing is at its path and at each parent's, then writes
its ``zarr.json`` and each parent group's if missing: five or six requests. Here zarr lays the array out in a
``MemoryStore`` (the same code, so the same ``zarr.json`` and chunk bytes) and the objects are written
concurrently, with only the checks the caller does not answer: the path is free (a GET, or a listing when
replacing, which deletes what it finds) and the parent groups exist (a HEAD for a group not known to exist).
Local stores are left to zarr (:func:`remote`).
"""

from __future__ import annotations

import asyncio
import posixpath
from collections.abc import Iterable
from typing import Any

import zarr
from zarr.core.array import AsyncArray
from zarr.core.sync import sync
from zarr.storage import FsspecStore, MemoryStore, StorePath
from zarr.storage._common import ensure_no_existing_node

__all__ = ["remote", "laid_out", "create", "write_all", "delete", "delete_all"]


def remote(group: zarr.Group) -> bool:
    """True when *group* lives on an fsspec (object) store, where :func:`create` saves requests."""
    return isinstance(group.store, FsspecStore)


def laid_out(name: str, options: dict[str, Any]) -> tuple[dict[str, Any], AsyncArray]:
    """The objects (key -> zarr buffer) and the array zarr writes for ``create_array(name=name, **options)``
    in an empty zarr v3 group: the array's ``zarr.json``, its parent groups' (the root's too) and the chunks of
    ``data``."""
    objects: dict[str, Any] = {}
    arr = zarr.create_array(MemoryStore(objects), name=name, zarr_format=3, **options)
    return objects, arr.async_array


def _parents(name: str) -> list[str]:
    parts = name.strip("/").split("/")[:-1]
    return ["/".join(parts[: i + 1]) for i in range(len(parts))]


async def _free(store: FsspecStore, name: str, overwrite: bool) -> None:
    if not overwrite:
        await ensure_no_existing_node(StorePath(store, name), zarr_format=3)  # ContainsArrayError, as zarr
        return
    await delete(store, name)


async def delete(store: FsspecStore, name: str) -> bool:
    """Delete every object under *name* (an array or a group) with one listing; False when there was none."""
    keys = [k async for k in store.list_prefix(name.strip("/") + "/")]
    if keys:
        await store.fs._rm([f"{store.path}/{k}" for k in keys])
    return bool(keys)


async def delete_all(store: FsspecStore, names: list[str]) -> list[str]:
    """Delete every object under each of *names* with one listing of their common group; the names there were."""
    parent = posixpath.commonpath(names) if len(names) > 1 else names[0]
    if not parent:  # no common group: one listing each
        return [n for n, there in zip(names, await asyncio.gather(*(delete(store, n) for n in names))) if there]
    keys = [k async for k in store.list_prefix(parent + "/")]
    doomed = [k for k in keys if k.startswith(tuple(n + "/" for n in names))]
    if doomed:
        await store.fs._rm([f"{store.path}/{k}" for k in doomed])
    return [n for n in names if any(k.startswith(n + "/") for k in doomed)]


async def _missing(store: FsspecStore, groups: Iterable[str]) -> list[str]:
    groups = list(groups)
    found = await asyncio.gather(*(store.exists(f"{g}/zarr.json") for g in groups))
    return [g for g, there in zip(groups, found) if not there]


async def _write(store: FsspecStore, objects: dict[str, Any]) -> None:
    await asyncio.gather(*(store.set(key, value) for key, value in objects.items()))


def write_all(group: zarr.Group, objects: dict[str, Any]) -> None:
    """Write *objects* (key -> zarr buffer) into *group*'s store concurrently."""
    sync(_write(group.store, objects))


def create(group: zarr.Group, name: str, options: dict[str, Any], *, overwrite: bool, groups: set[str],
           check: bool = True) -> zarr.Array:
    """``group.create_array(name, overwrite=overwrite, **options)`` on object storage in one batch of writes.

    *group* is a store's writable root; *groups* holds the group paths known to exist ("" the root), and gains
    those written. The objects are those zarr writes, and an existing node at *name* raises as in zarr
    (``ContainsArrayError``), or is deleted first when *overwrite*; *check* False: the caller knows the path is
    free (it deleted it).
    """
    store = group.store
    objects, laid = laid_out(name, options)

    async def run() -> list[str]:
        unknown = [g for g in _parents(name) if g not in groups]
        free = _free(store, name, overwrite) if check else asyncio.sleep(0)
        missing, _ = await asyncio.gather(_missing(store, unknown), free)
        skip = {"zarr.json"} | {f"{g}/zarr.json" for g in _parents(name) if g not in missing}
        await _write(store, {k: v for k, v in objects.items() if k not in skip})
        return _parents(name)

    groups.update(sync(run()))
    return zarr.Array(AsyncArray(metadata=laid.metadata, store_path=StorePath(store, name), config=laid.config))
