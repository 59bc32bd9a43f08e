"""Checks of LAS/LAZ files that laspy does not make, for clear errors on damaged files.

- :func:`check_layout`: the header's offsets and record counts fit in the
  file (laspy trusts them, and a flipped byte made it allocate gigabytes);
- :func:`decodable_points`: where the points of a truncated LAZ file stop
  decoding, for a message that names the point;
- :func:`decode_error`: the error of a failed decode, naming that point;
- :data:`QUIET_READS`: laspy's reader log is silenced while cloudsieve
  reads, which raises the error itself.

Used by :class:`cloudsieve.io.las.LasReader`.
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
    """Drops laspy's reader log records while cloudsieve reads a file.

    laspy logs a failed decompression (``ERROR laspy.lasreader: IoError:
    failed to fill whole buffer``, once per LAZ backend) and then raises; the
    reader raises :class:`CorruptInputError` with that text and the point
    where decoding failed, so the raw lines would only repeat it. Counted,
    not per thread: ingest reads in a background thread.
    """

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
    """A LAZ file seen with an empty chunk table appended (read-only, nothing written).

    A truncated LAZ file has lost its chunk table (stored at the end), so
    lazrs cannot open it. With fixed-size chunks the table is not needed to
    decode in order: this view points the table offset (the 8 bytes at the
    start of the point data) past the end of the file, where it shows an
    empty table (version 0, no chunk).
    """

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
    """How many points of the truncated LAZ file *path* decode in order before its data ends.

    Error path only: decodes the file again from its first point with lazrs
    alone (no chunk table needed, see :class:`_ChunkTableView`), LAZ chunk by
    LAZ chunk, then one point at a time within the chunk that fails (at most
    one LAZ chunk, 50,000 points by default). None when it cannot tell: the
    file is not truncated (its chunk table is in place: corrupt data may
    decode to garbage before it fails, so the failing chunk is all that is
    known), its chunks have variable sizes (COPC: they need the lost table),
    or lazrs is missing.
    """
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

    laspy trusts them: a flipped byte in an EVLR length made it allocate
    gigabytes (a MemoryError, or the memory actually taken), a huge VLR count
    loops. Only what the header says about where things are is checked: the
    point data offset, then the VLRs and EVLRs walked header by header.
    """
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
    """The error for points *done* to *last* of *path* failing to decode: it names the first point that fails.

    For LAZ with fixed-size chunks the point is exact (see
    :func:`decodable_points`); otherwise the message gives the points read.
    """
    decodable = decodable_points(path) if compressed else None
    if decodable is not None and decodable >= count:
        return CorruptInputError(
            f"{path}: every point decodes but the LAZ chunk table cannot be read ({exc}); truncated or corrupt")
    if decodable is not None and decodable >= done:
        decoded = f"points 0 to {decodable - 1} decode; " if decodable else ""
        return CorruptInputError(f"{path}: cannot decode point {decodable} of {count} ({decoded}{exc}); truncated or "
                                 f"corrupt")
    return CorruptInputError(f"{path}: cannot decode points {done} to {last} of {count} ({exc}); truncated or corrupt")
