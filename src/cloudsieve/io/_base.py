"""Reader and Writer base classes shared by the format modules.

A :class:`Reader` streams :class:`~cloudsieve.store.Chunk` ``(start, arrays)``
and never holds the whole file. A :class:`Writer` writes a temporary file
renamed to the destination only when the ``with`` block exits cleanly.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from typing import Any, BinaryIO

import numpy as np

from .. import storage
from ..atomic import check_destination, make_temp_path, remove, replace
from ..chunk import DEFAULT_CHUNK_SIZE, Chunk

__all__ = ["Reader", "Writer"]

logger = logging.getLogger(__name__)

Dtypes = dict[str, tuple[np.dtype, tuple]]


class Reader:
    """Streaming reader of one point cloud file (base class).
    Attributes: ``path``, ``format`` ("las", "laz", "copc", "ply", "e57", "xyz"), ``count`` (None only when unknown
    without a scan: XYZ), ``header`` (JSON-serialisable), ``dtypes`` (name -> (dtype, per-point shape), with
    ``"xyz": (float64, (3,))``), ``chunk_size``."""

    path: str
    format: str
    count: int | None
    header: dict
    dtypes: Dtypes
    chunk_size: int

    def __init__(self, path: str, format: str, chunk_size: int = DEFAULT_CHUNK_SIZE, **options: Any) -> None:
        self.path = path
        self.format = format
        self.chunk_size = int(chunk_size)
        self.options = options
        self.count = None
        self.header = {}
        self.dtypes = {"xyz": (np.dtype(np.float64), (3,))}

    def chunks(self) -> Iterator[Chunk]:
        """Yield :class:`~cloudsieve.store.Chunk` ``(start, arrays)`` of at most ``chunk_size`` points, in file order.
        ``arrays`` is ``{"xyz": (n, 3) float64, name: (n,) or (n, k), ...}``."""
        start = 0
        for arrays in self._read_chunks():
            yield Chunk(start, arrays)
            start += len(arrays["xyz"])

    def _read_chunks(self) -> Iterator[dict[str, np.ndarray]]:  # pragma: no cover - abstract
        """The format's blocks of points, as dicts (subclass hook)."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the file."""

    def __enter__(self) -> Reader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.path!r}, format={self.format!r}, count={self.count})"


class Writer:
    """Chunked writer to a temporary file renamed on clean exit (base class).
    Subclasses implement :meth:`_open` (``self.file`` is open), :meth:`_write` and :meth:`_close`. Attributes:
    ``path``, ``tmp_path``, ``count``."""

    def __init__(
        self,
        path: str,
        *,
        header: dict,
        dtypes: Dtypes,
        format: str,
        source_format: str | None = None,
        overwrite: bool = False,
        **options: Any,
    ) -> None:
        self.path = path
        self.format = format
        self.header = header or {}
        self.dtypes = {k: (np.dtype(v[0]), tuple(v[1])) for k, v in dtypes.items()}
        self.source_format = source_format
        self.options = options
        self.count = 0
        check_destination(path, overwrite)
        # a URL: written in a local temporary file (writers seek back to their header), then uploaded
        self._remote = storage.is_url(path)
        self.tmp_path = _local_temp(path) if self._remote else make_temp_path(path)
        self.file: BinaryIO = open(self.tmp_path, "wb")  # noqa: SIM115 - closed in __exit__
        self._done = False
        try:
            self._open()
        except BaseException:
            self._abort()
            raise
        from .conversions import conversion_note  # once the subclass knows its fields (a LAS writer's mapping)

        label = self.options.get("label", path)  # the file a message names (a part: the whole file)
        note = conversion_note(label, format, source_format, self.header, getattr(self, "_mapping", None))
        if note:
            logger.warning("%s", note)

    # subclass hooks ---------------------------------------------------------
    def _open(self) -> None:
        pass

    def _write(self, chunk: dict[str, np.ndarray]) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _close(self) -> None:
        pass

    # public -----------------------------------------------------------------
    def write(self, chunk: dict[str, np.ndarray]) -> None:
        """Append a chunk ``{"xyz": (n, 3), name: (n,) ...}`` of points."""
        n = len(chunk["xyz"])
        if n == 0:
            return
        self._write(chunk)
        self.count += n

    def _abort(self) -> None:
        try:
            self.file.close()
        finally:
            remove(self.tmp_path)
            self._done = True

    def __enter__(self) -> Writer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._done:
            return
        if exc_type is not None:
            try:
                self._abort_hook()
            except Exception:  # pragma: no cover - cleanup best effort
                pass
            self._abort()
            return
        try:
            self._close()
            if not self.file.closed:
                self.file.close()
        except BaseException:
            self._abort()
            raise
        if self._remote:
            try:
                storage.upload(self.tmp_path, self.path)
            finally:
                remove(self.tmp_path)
        else:
            replace(self.tmp_path, self.path)
        self._done = True
        logger.info("wrote %d points to %s", self.count, self.path)

    def _abort_hook(self) -> None:
        """Release format-specific resources after a failure (before the file is removed)."""


def _local_temp(path: str) -> str:
    """A new file in this process's temporary folder, named after the URL *path* (for its upload)."""
    import tempfile

    fd, tmp = tempfile.mkstemp(prefix=".cloudsieve-", suffix="-" + storage.name(path))
    os.close(fd)
    return tmp
