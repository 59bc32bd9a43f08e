"""Store handles opened once per stage in a worker process, not once per task.

Opening a store or an array reads its ``zarr.json`` (a request on object storage). Arrays change between stages
only, so a task marked by :func:`per_stage` keeps the groups and arrays it opens (and, on object storage, the
shard indexes read: :func:`remote_store`) for the stage's later tasks in its process; a task that creates or
deletes an array drops them (:func:`forget`). A leaf: zarr is imported at the first store opened.
"""

from __future__ import annotations

import functools
import threading
import uuid
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import zarr

__all__ = ["per_stage", "in_stage", "open_group", "once", "forget", "remote_store"]

_local = threading.local()  # .stage: the token of the stage whose task this thread runs (None: no task)
_lock = threading.Lock()
_kept: dict[tuple, Any] = {}  # (stage, path, mode[, name]) -> (group, meta) or an array; one stage's only


def per_stage(func: Callable) -> Callable:
    """*func* as the tasks of one stage: the store handles its calls open are kept for one another."""
    wrapped = functools.partial(_in_stage, uuid.uuid4().hex, func)
    wrapped.__name__ = getattr(func, "__name__", "task")  # the runner names the tasks' keys after it
    return wrapped


def _in_stage(token: str, func: Callable, *args):
    before = getattr(_local, "stage", None)
    _local.stage = token
    try:
        return func(*args)
    finally:
        _local.stage = before


def _stage() -> str | None:
    return getattr(_local, "stage", None)


def in_stage() -> bool:
    """True in a stage's task (what is opened is kept for the stage's later tasks in this process)."""
    return _stage() is not None


def open_group(path: str, mode: str, opener: Callable[[str, str], tuple[zarr.Group, dict]]) -> tuple[zarr.Group, dict]:
    """``opener(path, mode)`` (a store's group and its "cloudsieve" attributes), once per stage in a task:
    the group then keeps the arrays it looks up for the stage's later tasks. Outside a task, *opener*'s."""
    stage = _stage()
    if stage is None:
        return opener(path, mode)
    kept = _kept.get((stage, path, mode))
    if kept is None:
        group, meta = opener(path, mode)
        staged = _stage_group_class()(group._async_group)
        object.__setattr__(staged, "_where", (path, mode))
        kept = (staged, meta)
        _keep((stage, path, mode), kept)
    return kept


def once(key: tuple, make: Callable[[], Any]) -> Any:
    """``make()``, once per stage in a task for the same *key* (a tuple naming what it opens); outside a task,
    ``make()`` every time."""
    stage = _stage()
    if stage is None:
        return make()
    got = _kept.get((stage, "once", *key))
    if got is None:
        got = make()
        _keep((stage, "once", *key), got)
    return got


def _keep(key: tuple, value: Any) -> None:
    with _lock:
        if any(k[0] != key[0] for k in _kept):  # a new stage: the last one's handles go
            _kept.clear()
        _kept[key] = value


def forget() -> None:
    """Drop every kept handle of this process (an array was created or deleted)."""
    with _lock:
        _kept.clear()


@functools.cache
def _stage_group_class() -> type:
    import zarr  # here: the runner imports this module, and no zarr with it

    return type("StageGroup", (_StageLookups, zarr.Group), {})


class _StageLookups:
    """What a zarr group whose lookups in a stage's task are kept for the stage's later tasks does differently."""

    def _key(self, name: str) -> tuple | None:
        stage = _stage()
        return None if stage is None else (stage, *getattr(self, "_where"), str(name).strip("/"))

    def __getitem__(self, path: str):
        key = self._key(path)
        node = None if key is None else _kept.get(key)
        if node is None:
            node = super().__getitem__(path)  # type: ignore[misc]
            if key is not None and not hasattr(node, "members"):  # an array (a group has members)
                _keep(key, node)
        return node

    def array_keys(self) -> Iterator[str]:
        key = self._key("/array_keys")  # not an array name: a name has no leading "/"
        names = None if key is None else _kept.get(key)
        if names is None:
            names = tuple(super().array_keys())  # type: ignore[misc]
            if key is not None:
                _keep(key, names)
        return iter(names)

    def __contains__(self, member: str) -> bool:
        key = self._key(member)
        if key is not None and key in _kept:
            return True
        return super().__contains__(member)  # type: ignore[misc]


def remote_store(make: Callable[[], Any]) -> Any:
    """``make()``, a zarr ``FsspecStore``; opened in a stage's task, one that keeps the shard indexes it reads
    (suffix reads) until it writes or deletes that object: the store lives as long as the stage's group."""
    store = make()
    if _stage() is None:
        return store
    store.__class__ = _stage_store_class(type(store))
    object.__setattr__(store, "_indexes", {})
    return store


@functools.cache
def _stage_store_class(base: type) -> type:
    from zarr.abc.store import SuffixByteRequest

    class StageStore(base):  # type: ignore[valid-type, misc]
        async def get(self, key, prototype, byte_range=None):
            if not isinstance(byte_range, SuffixByteRequest):
                return await super().get(key, prototype, byte_range)
            got = self._indexes.get((key, byte_range.suffix))
            if got is None:
                got = await super().get(key, prototype, byte_range)
                if got is not None:
                    self._indexes[(key, byte_range.suffix)] = got
            return got

        async def set(self, key, value, *args, **kwargs):
            self._forget(key)
            return await super().set(key, value, *args, **kwargs)

        async def delete(self, key):
            self._forget(key)
            return await super().delete(key)

        def _forget(self, key) -> None:
            for k in [k for k in self._indexes if k[0] == key]:
                del self._indexes[k]

    return StageStore
