"""Checks of LAS/LAZ files that laspy does not make, for clear errors on damaged files.

:func:`check_layout` (header offsets and counts fit the file),
:func:`decodable_points` and :func:`decode_error` (name the first point of a
LAZ file that fails to decode), :data:`QUIET_READS` (laspy's reader log
silenced while cloudsieve reads and raises itself). Used by
:class:`cloudsieve.io.las.LasReader`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import threading

from .. import storage
from ..errors import CorruptInputError

__all__ = ["QuietReads", "QUIET_READS", "check_layout", "decodable_points", "decode_error"]


class QuietReads(logging.Filter):
    """Drops laspy's reader log records while cloudsieve reads a file (its error repeats them).
    Counted, not per thread: ingest reads in a background thread."""

    def __init__(self) -> None:
        super().__init__()
        self.active = 0
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        return self.active == 0

    @contextlib.contextmanager
    def reading(self):
        with self._lock:
            self.active += 1
        try:
            yield
        finally:
            with self._lock:
                self.active -= 1


QUIET_READS = QuietReads()
logging.getLogger("laspy.lasreader").addFilter(QUIET_READS)


class _ChunkTableView(io.RawIOBase):
    """A LAZ file seen with an empty chunk table appended (read-only).
    A truncated LAZ file has lost its chunk table (at its end); with fixed-size chunks lazrs decodes in order
    without it, so this view points the table offset past the end of the file, at an empty table."""

    def __init__(self, path: str, offset_to_points: int) -> None:
        self._file = open(path, "rb")  # noqa: SIM115 - closed in close()
        self._size = os.path.getsize(path)
        self._patches = [(offset_to_points, self._size.to_bytes(8, "little", signed=True)), (self._size, bytes(8))]
        self._end = self._size + 8
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = 0) -> int:
        self._pos = {0: 0, 1: self._pos, 2: self._end}[whence] + offset
        return self._pos

    def readinto(self, buffer) -> int:
        n = min(len(buffer), max(self._end - self._pos, 0))
        if n <= 0:
            return 0
        self._file.seek(self._pos)
        data = bytearray(self._file.read(min(n, max(self._size - self._pos, 0))))
        data.extend(bytes(n - len(data)))
        for start, patch in self._patches:
            lo, hi = max(start, self._pos), min(start + len(patch), self._pos + n)
            if lo < hi:
                data[lo - self._pos : hi - self._pos] = patch[lo - start : hi - start]
        buffer[:n] = data
        self._pos += n
        return n

    def close(self) -> None:
        self._file.close()
        super().close()


def decodable_points(path: str) -> int | None:
    """How many points of the truncated LAZ file *path* decode in order before its data ends (error path only).
    Decodes again with lazrs, LAZ chunk by chunk, then point by point within the failing chunk. None when it cannot
    tell: the chunk table is in place (not truncated), chunks have variable sizes (COPC), or lazrs is missing."""
    try:
        import lazrs

        from .las_layout import laszip_vlr, read_header

        h = read_header(path)
        laz = laszip_vlr(h)
        with open(path, "rb") as fh:
            fh.seek(h.offset_to_point_data)
            table = int.from_bytes(fh.read(8), "little", signed=True)
        if table <= os.path.getsize(path) - 8:  # the chunk table is in the file: not truncated
            return None
        if laz.uses_variable_size_chunks():
            return None
        step, psize, count = int(laz.chunk_size()), h.point_format.size, int(h.point_count)
    except Exception:  # the header itself is unreadable: nothing to tell
        return None
    buffer = memoryview(bytearray(step * psize))

    def decoded(limit: int, one_by_one_after: int | None) -> int:
        with _ChunkTableView(path, h.offset_to_point_data) as view:
            view.seek(h.offset_to_point_data)
            decoder = lazrs.LasZipDecompressor(view, laz.record_data())
            done = 0
            while done < limit:
                k = 1 if one_by_one_after is not None and done >= one_by_one_after else min(step, limit - done)
                try:
                    decoder.decompress_many(buffer[: k * psize])
                except Exception:
                    return done
                done += k
            return done

    try:
        good = decoded(count, None)  # whole LAZ chunks: the failing chunk starts at *good*
        if good >= count:
            return count
        return decoded(min(good + step, count), good)
    except Exception:  # lazrs refuses the view: nothing to tell
        return None


def check_layout(path: str) -> None:
    """Refuse a LAS header whose record counts and offsets point past the file, before laspy reads it.
    laspy trusts them, and a flipped byte can make it allocate gigabytes. Checks the point data offset, then walks
    the VLRs and EVLRs."""
    size = storage.size(path)
    with storage.open_input(path, storage.HEADER_BLOCK) as fh:
        head = fh.read(375)
        if len(head) < 227 or head[:4] != b"LASF":
            return  # laspy refuses it, with its own message
        header_size = int.from_bytes(head[94:96], "little")
        offset = int.from_bytes(head[96:100], "little")
        n_vlrs = int.from_bytes(head[100:104], "little")
        if not header_size <= offset <= size:
            raise CorruptInputError(
                f"{path}: the header puts the points at byte {offset} (header {header_size} bytes, file {size}); "
                f"corrupt header")
        fh.seek(header_size)
        region = fh.read(offset - header_size)
        pos = 0
        for i in range(n_vlrs):
            if pos + 54 > len(region):
                raise CorruptInputError(f"{path}: the header lists {n_vlrs} VLRs but only {i} fit before the points "
                                        f"(corrupt header)")
            pos += 54 + int.from_bytes(region[pos + 20 : pos + 22], "little")  # record length after the header
        if head[25] < 4 or len(head) < 247:
            return
        pos = int.from_bytes(head[235:243], "little")
        n_evlrs = int.from_bytes(head[243:247], "little")
        for i in range(n_evlrs):
            evlr = b""
            if pos + 60 <= size:
                fh.seek(pos)
                evlr = fh.read(60)
            length = int.from_bytes(evlr[20:28], "little") if len(evlr) == 60 else 0
            if len(evlr) < 60 or pos + 60 + length > size:
                raise CorruptInputError(f"{path}: the header lists {n_evlrs} extended VLRs but only {i} fit in the "
                                        f"file (truncated or corrupt)")
            pos += 60 + length


def decode_error(path: str, count: int, compressed: bool, done: int, last: int, exc: Exception) -> CorruptInputError:
    """The error for points *done* to *last* of *path* failing to decode, naming the first failing point when known."""
    decodable = decodable_points(path) if compressed else None
    if decodable is not None and decodable >= count:
        return CorruptInputError(
            f"{path}: every point decodes but the LAZ chunk table cannot be read ({exc}); truncated or corrupt")
    if decodable is not None and decodable >= done:
        decoded = f"points 0 to {decodable - 1} decode; " if decodable else ""
        return CorruptInputError(f"{path}: cannot decode point {decodable} of {count} ({decoded}{exc}); truncated or "
                                 f"corrupt")
    return CorruptInputError(f"{path}: cannot decode points {done} to {last} of {count} ({exc}); truncated or corrupt")
