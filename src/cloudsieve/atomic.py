"""Atomic outputs: a file or folder written under a temporary name beside its destination, then renamed.

On an object store a file is uploaded whole (or never appears) and a folder of tiles is committed by its
``index.vpc``, written last. A leaf (imports :mod:`cloudsieve.errors` and :mod:`cloudsieve.storage`),
used by every writer: a failed write leaves nothing under the destination's name.

>>> check_destination(dst, overwrite)  # doctest: +SKIP
>>> tmp = make_temp_path(dst)
>>> try:
...     write(tmp)
...     replace(tmp, dst)
... finally:
...     remove(tmp)  # gone after replace: nothing to do
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from .errors import DestinationExistsError, DestinationNotWritableError
from .storage import is_url

__all__ = ["check_destination", "make_temp_path", "current_umask", "replace", "remove", "replacing", "write_text"]

logger = logging.getLogger(__name__)


def check_destination(path: str, overwrite: bool, *, folder: bool = False,
                      foreign: Callable[[str], str | None] | None = None) -> None:
    """Refuse a destination that exists (unless *overwrite*), is of the other kind, or cannot be written.
    *folder*: the destination is a folder (never replaced by a file, nor a file by a folder). An existing folder is
    replaced only when ``foreign(path)`` returns None (else a description of what cloudsieve did not write there).
    Raises DestinationExistsError, or DestinationNotWritableError when the parent folder is missing."""
    if is_url(path):
        _check_remote(path, overwrite, folder, foreign)
        return
    is_dir = os.path.isdir(path)
    _check_kind(path, overwrite, folder, foreign, is_dir=is_dir, is_file=not is_dir and os.path.lexists(path))
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.exists(parent):
        raise DestinationNotWritableError(f"cannot write {path}: folder {parent} does not exist")
    if not os.path.isdir(parent):
        raise DestinationNotWritableError(f"cannot write {path}: {parent} is not a folder")


def _check_remote(path: str, overwrite: bool, folder: bool, foreign) -> None:
    """:func:`check_destination` for a URL: an object (a file) or a prefix (a folder of objects); the bucket
    must exist."""
    from . import storage

    fs, p = storage.filesystem(path)
    bucket = p.split("/", 1)[0]
    with storage.remote_errors(path, writing=True):
        if not fs.exists(bucket):
            raise DestinationNotWritableError(f"cannot write {path}: bucket {bucket} does not exist")
        # an empty object written and removed: credentials that cannot write fail now, before any work
        head, _, tail = p.rstrip("/").rpartition("/")
        probe = f"{head}/.{tail}.cloudsieve-probe-{uuid.uuid4().hex[:12]}"
        fs.pipe_file(probe, b"")
        fs.rm(probe)
    is_file = storage.isfile(path)
    _check_kind(path, overwrite, folder, foreign, is_dir=not is_file and storage.isdir(path), is_file=is_file)


def _check_kind(path: str, overwrite: bool, folder: bool, foreign, *, is_dir: bool, is_file: bool) -> None:
    """The refusals of :func:`check_destination` for what is at *path* (a folder or prefix, a file or object)."""
    if is_dir:
        if not folder:
            raise DestinationExistsError(f"{path} is a folder: cloudsieve never replaces a folder with a file "
                                         "(remove it, or choose another name)")
        if not overwrite:
            raise DestinationExistsError(f"{path} exists (a folder); pass overwrite=True to replace it",
                                         advice={"overwrite": True})
        found = foreign(path) if foreign is not None else None
        if found is not None:
            raise DestinationExistsError(f"{path} holds {found}: cloudsieve replaces only a folder of its own "
                                         "output (remove it, or choose another name)")
    elif is_file:
        if folder:
            raise DestinationExistsError(f"{path} is a file: cloudsieve never replaces a file with a folder "
                                         "(remove it, or choose another name)")
        if not overwrite:
            raise DestinationExistsError(f"{path} exists; pass overwrite=True to replace it",
                                         advice={"overwrite": True})


def current_umask() -> int:
    """The process's umask (read from /proc where it can be, so it is never changed, even for a moment)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # pragma: no cover - no /proc (macOS): set and restore
    os.umask(mask)  # pragma: no cover
    return mask  # pragma: no cover


def make_temp_path(path: str, *, directory: bool = False) -> str:
    """Create (and return) a temporary file or folder beside *path*, with the mode a new file gets under the umask
    (not ``mkstemp``'s private 0600/0700)."""
    parent = os.path.dirname(os.path.abspath(path))
    prefix = "." + os.path.basename(path) + "."
    try:
        if directory:
            tmp = tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=parent)
            os.chmod(tmp, 0o777 & ~current_umask())
            return tmp
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=parent)
        try:
            os.fchmod(fd, 0o666 & ~current_umask())
        finally:
            os.close(fd)
        return tmp
    except OSError as exc:
        raise DestinationNotWritableError(f"cannot write {path}: {exc.strerror or exc}") from exc


def replace(tmp: str, path: str) -> None:
    """Move *tmp* to *path* (replacing a file or a folder there)."""
    try:
        if os.path.isdir(path) and not os.path.islink(path):
            trash = make_temp_path(path, directory=True)
            os.rmdir(trash)
            os.replace(path, trash)
            os.replace(tmp, path)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except OSError as exc:
        raise DestinationNotWritableError(f"cannot write {path}: {exc.strerror or exc}") from exc


def remove(path: str) -> None:
    """Remove a temporary file or folder, ignoring errors."""
    try:
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        elif os.path.lexists(path):
            os.remove(path)
    except OSError:  # pragma: no cover - best effort
        logger.warning("could not remove temporary %s", path)


@contextmanager
def replacing(path: str, *, directory: bool = False) -> Iterator[str]:
    """A temporary name beside *path* to write (:func:`make_temp_path`), renamed to *path* when the block ends
    without error, removed on an error."""
    tmp = make_temp_path(path, directory=directory)
    try:
        yield tmp
        replace(tmp, path)
    except BaseException:
        remove(tmp)
        raise


def write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    """Write *text* to *path* atomically (a temporary file renamed); DestinationNotWritableError if the folder is not
    writable."""
    with replacing(os.fspath(path)) as tmp, open(tmp, "w", encoding=encoding) as fh:
        fh.write(text)
