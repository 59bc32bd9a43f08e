"""Where the bytes live: local paths and fsspec URLs (``s3://``, ``gs://``, ``az://``, ``http(s)://`` for
reading, ``memory://``), with a run's storage options.

A leaf. Every module that opens, lists or removes a cloud, list, VPC or store goes through it, so a URL works
wherever a path does: :func:`open_input` reads by ranged requests, :func:`open_output` writes (multipart on S3).
Storage options are a dict for the URL's filesystem (s3fs: ``key``, ``secret``, ``endpoint_url``), else the
ecosystem's chain (``AWS_*``, config files, roles); :func:`using` sets them in the driver, :func:`bound` hands
them to tasks. They are never logged, stored, or printed in an error (:func:`redact`).
"""

from __future__ import annotations

import contextlib
import copy
import functools
import logging
import os
import posixpath
import re
from collections.abc import Callable, Iterator
from urllib.parse import unquote, urlparse

from . import storage_errors, storage_retries
from .errors import InvalidParameterError

__all__ = ["is_url", "local", "protocol", "current", "using", "bound", "filesystem", "open_input",
           "widen", "open_output", "fs_options", "exists", "isfile", "isdir", "listdir", "glob", "join", "parent",
           "name", "identity", "size", "read_range", "write_bytes", "upload", "discard", "remove", "redact", "remote_errors", "READ_BLOCK", "HEADER_BLOCK", "COPY_BLOCK"]

logger = logging.getLogger(__name__)

#: a remote file's read-ahead: one ranged request fetches at least this many bytes; a task reads at most one
#: block past its chunks, so a run reads about its input's bytes once
READ_BLOCK = 256 * 2**10
#: the read-ahead of an opening that reads a header alone (the LAS header and its VLRs, a few KiB)
HEADER_BLOCK = 16 * 2**10
#: one ranged read of a copy from object to object (the parts of a file assembled into it)
COPY_BLOCK = 8 * 2**20
#: a remote file's write buffer: a multipart upload's part (S3's minimum part size is 5 MiB)
WRITE_BLOCK = 16 * 2**20

_OPTIONS: dict = {}
#: the options an S3 filesystem gets unless the run's say otherwise: a bounded connect time, transient errors
#: retried, 4 attempts; copied per filesystem (botocore rewrites "retries" in place)
_S3_DEFAULTS = {"config_kwargs": {"connect_timeout": 10, "read_timeout": 60,
                                  "retries": {"total_max_attempts": 4, "mode": "standard"}}}


def is_url(path: str | os.PathLike) -> bool:
    """True for an fsspec URL other than ``file://`` (that one is the local path it names)."""
    path = os.fspath(path)
    return "://" in path and not path.startswith("file://")


def local(path: str | os.PathLike) -> str | None:
    """The local file-system path behind *path* (absolute), or None for a remote URL."""
    path = os.fspath(path)
    if "://" not in path:
        return os.path.abspath(path)
    url = urlparse(path)
    if url.scheme == "file":
        return os.path.abspath(unquote(url.netloc + url.path))
    return None


def protocol(path: str | os.PathLike) -> str:
    """The URL's protocol ("s3", "gs", ...), "file" for a local path."""
    path = os.fspath(path)
    return path.split("://", 1)[0].lower() if "://" in path else "file"


def current() -> dict:
    """The storage options in force in this process (a copy)."""
    return dict(_OPTIONS)


@contextlib.contextmanager
def using(options: dict | None) -> Iterator[None]:
    """Run the block with *options* as this process's storage options (restored after); None keeps the
    options in force (a pipeline's, around its stages)."""
    global _OPTIONS
    if options is not None and not isinstance(options, dict):
        raise InvalidParameterError(f"storage_options must be a dict of the filesystem's options, got "
                                    f"{type(options).__name__}")
    saved = _OPTIONS
    _OPTIONS = dict(saved if options is None else options)
    try:
        yield
    finally:
        _OPTIONS = saved


def _call_with(options: dict, func: Callable, *args):
    with using(options):
        return func(*args)


def bound(func: Callable, options: dict | None = None) -> Callable:
    """*func* run with *options* (default: this process's) as its storage options, wherever it runs (a task)."""
    options = current() if options is None else options
    if not options:
        return func
    wrapped = functools.partial(_call_with, options, func)
    wrapped.__name__ = getattr(func, "__name__", "task")  # the runner names the tasks' keys after it
    return wrapped


def fs_options(path: str) -> dict:
    """The options the filesystem of *path* is made with: the run's, with S3's bounded time-outs and retries."""
    return _options_for(protocol(path))


def _options_for(proto: str) -> dict:
    storage_retries.watch(proto)  # a remote filesystem: the run touches a URL; S3's retries are counted
    options = dict(_OPTIONS)
    # other processes (the workers) write the objects this one lists: no listing is cached
    options.setdefault("use_listings_cache", False)
    if proto in ("s3", "s3a"):
        # fresh copies: a dict botocore rewrote would name another filesystem (a second S3 client, ~0.1 s CPU)
        config = copy.deepcopy({**_S3_DEFAULTS["config_kwargs"], **options.get("config_kwargs", {})})
        options["config_kwargs"] = config
    return options


def filesystem(path: str | os.PathLike):
    """``(fs, path_in_fs)`` of *path*: its fsspec filesystem, made with the run's storage options."""
    import fsspec

    path = os.fspath(path)
    proto = protocol(path)
    with remote_errors(path):
        return fsspec.core.url_to_fs(path, **(_options_for(proto) if proto != "file" else {}))


def open_input(path: str | os.PathLike, block_size: int = READ_BLOCK):
    """A binary file object for reading *path*; a URL reads by ranged requests of at least *block_size* bytes
    (a header: small; a run of LAZ chunks: large)."""
    path = os.fspath(path)
    if not is_url(path):
        return open(local(path), "rb")
    fs, p = filesystem(path)
    with remote_errors(path):
        fh = fs.open(p, "rb", block_size=block_size, cache_type="readahead")
    fetch = getattr(fh.cache, "fetcher", None)
    if fetch is not None:  # each ranged request of a read: its errors are cloudsieve's too
        def mapped_fetch(start: int, end: int) -> bytes:
            with remote_errors(path):
                return fetch(start, end)

        fh.cache.fetcher = mapped_fetch
    return fh


def widen(fh, block_size: int = READ_BLOCK) -> None:
    """Give the file *fh* of :func:`open_input` a larger read-ahead from here on (a header was read with a
    small one; the data that follows with this one). A local file reads as it did."""
    cache = getattr(fh, "cache", None)
    if cache is not None and hasattr(cache, "blocksize"):
        cache.blocksize = block_size
        fh.blocksize = block_size


def open_output(path: str | os.PathLike):
    """A binary file object writing *path* (a URL: uploaded in parts of :data:`WRITE_BLOCK`, complete only
    when closed without error)."""
    path = os.fspath(path)
    if not is_url(path):
        return open(local(path), "wb")
    fs, p = filesystem(path)
    with remote_errors(path, writing=True):
        return fs.open(p, "wb", block_size=WRITE_BLOCK)


def exists(path: str | os.PathLike) -> bool:
    path = os.fspath(path)
    if not is_url(path):
        return os.path.exists(local(path))
    fs, p = filesystem(path)
    with remote_errors(path):
        return fs.exists(p)


def isfile(path: str | os.PathLike) -> bool:
    path = os.fspath(path)
    if not is_url(path):
        return os.path.isfile(local(path))
    fs, p = filesystem(path)
    with remote_errors(path):
        return fs.isfile(p)


def isdir(path: str | os.PathLike) -> bool:
    """A local folder; for a URL, a prefix holding at least one object (object stores have no folders; a
    folder some of them keep once emptied counts as absent)."""
    path = os.fspath(path)
    if not is_url(path):
        return os.path.isdir(local(path))
    fs, p = filesystem(path)
    with remote_errors(path):
        # some stores list a folder's own marker (an empty key ending in "/") among its objects
        return not fs.isfile(p) and any(k.rstrip("/") != p.rstrip("/") for k in fs.find(p))


def listdir(path: str | os.PathLike, files_only: bool = True) -> list[str]:
    """The names of the files (with *files_only* False, also the folders or sub-prefixes) directly in the
    folder or prefix *path*, sorted."""
    path = os.fspath(path)
    if not is_url(path):
        folder = local(path)
        return sorted(n for n in os.listdir(folder) if not files_only or os.path.isfile(os.path.join(folder, n)))
    fs, p = filesystem(path)
    with remote_errors(path):
        entries = fs.ls(p, detail=True, refresh=True)
    return sorted(posixpath.basename(e["name"].rstrip("/")) for e in entries
                  if not files_only or e.get("type") == "file")


def glob(pattern: str) -> list[str]:
    """The files matching *pattern*, sorted, as URLs of the pattern's protocol (local: paths)."""
    import glob as _glob

    if not is_url(pattern):
        return sorted(p for p in _glob.glob(pattern) if os.path.isfile(p))
    fs, p = filesystem(pattern)
    with remote_errors(pattern):
        found = fs.glob(p, detail=True)
    proto = protocol(pattern)
    return sorted(f"{proto}://{k.lstrip('/')}" for k, v in found.items() if v.get("type") == "file")


def join(base: str, relative: str) -> str:
    """*relative* resolved against the folder *base* (a URL stays a URL; an absolute path or URL is kept)."""
    if "://" in relative or os.path.isabs(relative) and not is_url(base):
        return relative
    if is_url(base):
        proto, rest = base.split("://", 1)
        return f"{proto}://{posixpath.normpath(posixpath.join(rest, relative))}"
    return os.path.join(base, relative)


def parent(path: str) -> str:
    """The folder (or prefix) holding *path*."""
    if is_url(path):
        proto, rest = path.rstrip("/").split("://", 1)
        return f"{proto}://{posixpath.dirname(rest)}"
    return os.path.dirname(os.path.abspath(path))


def name(path: str) -> str:
    """The last part of *path*."""
    return posixpath.basename(path.rstrip("/")) if is_url(path) else os.path.basename(path.rstrip("/"))


def identity(path: str) -> tuple[int, str]:
    """``(size in bytes, version)`` of the file *path*, telling a changed file for a resume (mtime in ns; an
    object's ETag, else its mtime)."""
    if not is_url(path):
        st = os.stat(local(path))
        return int(st.st_size), str(st.st_mtime_ns)
    fs, p = filesystem(path)
    with remote_errors(path):
        info = fs.info(p)
    version = info.get("ETag") or info.get("etag") or info.get("LastModified") or info.get("mtime") or ""
    return int(info.get("size") or 0), str(version).strip('"')


def size(path: str) -> int:
    """The size in bytes of the file *path*."""
    if not is_url(path):
        return os.path.getsize(local(path))
    return identity(path)[0]


def read_range(path: str, start: int, length: int) -> bytes:
    """*length* bytes of the file *path* from *start* (one ranged request for a URL)."""
    if not is_url(path):
        with open(local(path), "rb") as fh:
            fh.seek(start)
            return fh.read(length)
    fs, p = filesystem(path)
    with remote_errors(path):
        return fs.cat_file(p, start=start, end=start + length)


def discard(fh) -> None:
    """Drop the file *fh* of :func:`open_output` after a failure: an unfinished upload is aborted (nothing
    appears); a local file is closed (its caller removes it)."""
    try:
        if hasattr(fh, "discard"):
            fh.discard()
            fh.closed = True  # else its finaliser flushes the dropped buffer
        else:
            fh.close()
    except Exception:  # noqa: BLE001 - the failure that led here is the one to report
        pass


def write_bytes(path: str, data: bytes) -> None:
    """Write the small file *path* in one request (an object appears whole or not at all)."""
    fs, p = filesystem(path)
    with remote_errors(path, writing=True):
        fs.pipe_file(p, data)


def upload(local_file: str, path: str) -> None:
    """Copy the local file *local_file* to the URL *path* (a multipart upload above s3fs's part size: the
    object appears when every part is in, or not at all)."""
    fs, p = filesystem(path)
    with remote_errors(path, writing=True):
        fs.put_file(local_file, p)


def remove(path: str, recursive: bool = False) -> None:
    """Remove the file (or with *recursive* the folder or prefix) *path*; a missing one is ignored."""
    import shutil

    if not is_url(path):
        p = local(path)
        if os.path.isdir(p) and not os.path.islink(p):
            if recursive:
                shutil.rmtree(p, ignore_errors=True)
        elif os.path.lexists(p):
            os.remove(p)
        return
    fs, p = filesystem(path)
    with remote_errors(path, writing=True):
        try:
            fs.rm(p, recursive=recursive)
        except FileNotFoundError:
            return
    # a bulk delete reports a refused key in its answer, not as an error: look again (a clean-up: said, not raised)
    if recursive and isdir(path) or not recursive and isfile(path):
        logger.warning("could not remove %s (the object store refused to delete it)", path)


def redact(text: str) -> str:
    """*text* with anything that looks like a credential, and the run's own secrets, masked."""
    return storage_errors.redact(text, _secret_values())


def _secret_values() -> list[str]:
    return [v for k, v in _OPTIONS.items()
            if isinstance(v, str) and len(v) >= 4 and re.search(r"(?i)secret|token|key|password", k)]


def _endpoint() -> str | None:
    return (_OPTIONS.get("endpoint_url") or _OPTIONS.get("client_kwargs", {}).get("endpoint_url")
            or os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL"))


def remote_errors(path: str, writing: bool = False):
    """A context in which an object store's errors about *path* become cloudsieve's own, one line naming
    *path* (and the endpoint when it cannot be reached), with no credential in it
    (:func:`cloudsieve.storage_errors.mapped`)."""
    return storage_errors.mapped(path, is_url(path), writing, _endpoint(), _secret_values())
