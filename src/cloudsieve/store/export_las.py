"""Point store -> one LAS/LAZ file, as tasks: :func:`export_las`.

Each task writes a part of whole LAZ chunks as a complete file; the driver
only concatenates bytes. The file is byte for byte the one
:func:`cloudsieve.store.export` writes in one stream.
"""

from __future__ import annotations

import logging
import os
import struct

import numpy as np

from .. import storage
from .pointstore import PointStore
from .streaming import bound_malloc, run_tasks

__all__ = ["export_las", "part_task", "LAZ_CHUNK"]

logger = logging.getLogger(__name__)

#: points per LAZ chunk (laspy's, so a part boundary is a chunk boundary)
LAZ_CHUNK = 50_000


def _kept_rows(store: PointStore, mask: str | None, start: int, stop: int) -> np.ndarray | None:
    if mask is None:
        return None
    return np.flatnonzero(np.asarray(store.array(mask)[start:stop], dtype=bool))


def count_task(store_path: str, mask: str, start: int, stop: int) -> int:
    """Kept points in rows ``[start, stop)`` (a task)."""
    st = PointStore.open(store_path, "r")
    return int(np.count_nonzero(np.asarray(st.array(mask)[start:stop], dtype=bool)))


class _Quiet(logging.Filter):
    """Drops the header and conversion warnings every part repeats (the first part gives them)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno < logging.WARNING


def part_task(store_path: str, part_path: str, fmt: str, mask: str | None, chunks: list[tuple[int, int, int, int]],
              label: str, first: bool) -> int:
    """Task: write one part, for each store rows ``[start, stop)`` its kept points ``lo:hi``; points written.

    *label* names the whole file in messages; only the *first* part warns.
    """
    bound_malloc()
    st = PointStore.open(store_path, "r")
    quiet = _Quiet()
    logs = [logging.getLogger(name) for name in ("cloudsieve.io.las_header", "cloudsieve.io._base")]
    for log in logs if not first else []:
        log.addFilter(quiet)
    try:
        return _write_part(st, part_path, fmt, mask, chunks, label)
    finally:
        for log in logs:
            log.removeFilter(quiet)


def _write_part(st: PointStore, part_path: str, fmt: str, mask: str | None, chunks, label: str) -> int:
    """One part; from a LAS source its records are packed at once (:class:`cloudsieve.io.las.LasPacking`) and
    written as they are, LAZ on one thread (a task owns a core): the bytes of the writer's own assembly. An empty
    part keeps the default backend: lazrs' two compressors end a file of no point differently."""
    from ..io import open_writer
    from ..io.las import LasPacking, las_sourced, laz_backend

    packing = LasPacking(st.header, st.dimensions, label) if las_sourced(st.source_format, st.header) else None
    backend = laz_backend(parallel=not any(hi > lo for _, _, lo, hi in chunks))
    written = 0
    with open_writer(part_path, header=st.header, dtypes=st.dtypes, format=fmt, source_format=st.source_format,
                     overwrite=True, bounds=st.bounds, label=label, laz_backend=backend) as writer:
        for start, stop, lo, hi in chunks:
            chunk = st.rows(start, stop)
            rows = _kept_rows(st, mask, start, stop)
            if rows is None:
                rows = np.arange(stop - start)
            rows = rows[lo:hi]
            if packing is None:
                writer.write({k: v.take(rows, axis=0) for k, v in chunk.items()})
            elif len(rows):
                writer.write_records(packing(chunk.pop("xyz"), chunk, rows, rows))
            written += len(rows)
    return written


def _plan(counts: np.ndarray, chunk_size: int, n: int, part_size: int) -> list[list[tuple[int, int, int, int]]]:
    """Per part of *part_size* kept points: store rows ``(start, stop)`` and the slice ``lo:hi`` of their kept
    points (one empty part when nothing is kept)."""
    ends = np.cumsum(counts)
    starts = ends - counts
    total = int(ends[-1]) if len(ends) else 0
    parts = []
    for k_lo in range(0, max(total, 1), part_size):
        k_hi = min(k_lo + part_size, total)
        items = []
        for c in range(int(np.searchsorted(ends, k_lo, side="right")), len(counts)):
            if starts[c] >= k_hi:
                break
            a, b = max(k_lo, int(starts[c])), min(k_hi, int(ends[c]))
            items.append((c * chunk_size, min((c + 1) * chunk_size, n), a - int(starts[c]), b - int(starts[c])))
        parts.append(items)
    return parts


def _parts_plan(store: PointStore, mask, run, counts, part_size) -> tuple[np.ndarray, list]:
    """The kept points per store chunk (counted by tasks when not known) and the parts' plan (:func:`_plan`)."""
    n, step = store.count, store.chunk_size
    bounds = [(s, min(s + step, n)) for s in range(0, n, step)]
    if counts is None:
        if mask is None:
            counts = [b - a for a, b in bounds]
        else:
            args = [(store.path, mask, a, b) for a, b in bounds]
            counts = run_tasks(run, count_task, args, "export: count")
    counts = np.asarray(counts, dtype=np.int64)
    part_size = int(part_size or max(1, round(step / LAZ_CHUNK)) * LAZ_CHUNK)
    return counts, _plan(counts, step, n, part_size)


def export_las(store: PointStore, dst: str, *, fmt: str, mask: str | None = None, run=None,
               counts: list[int] | None = None, overwrite: bool = False, part_size: int | None = None) -> int:
    """Write the points of *store* kept by the bool array *mask* to the LAS/LAZ file *dst*, as tasks.

    *dst* is written under a temporary name and renamed; *fmt* "las" or
    "laz"; *mask* None keeps every point; *run* None runs the tasks here;
    *counts*: kept points per store chunk when known (the merge's);
    *part_size*: points per task, a multiple of :data:`LAZ_CHUNK` (default
    about a store chunk). Returns the points written.
    """
    from ..atomic import check_destination, make_temp_path, remove, replacing

    check_destination(dst, overwrite)
    if storage.is_url(dst):
        return _export_remote(store, dst, fmt, mask, run, counts, part_size)
    counts, plan = _parts_plan(store, mask, run, counts, part_size)
    tmp = make_temp_path(dst, directory=True)
    suffix = "." + fmt
    try:
        args = [(store.path, os.path.join(tmp, f"part-{i:06d}{suffix}"), fmt, mask, items, dst, i == 0)
                for i, items in enumerate(plan)]
        written = run_tasks(run, part_task, args, "export: write")
        with replacing(dst) as final:
            if len(args) == 1:
                os.replace(args[0][1], final)
            else:
                splice([a[1] for a in args], final, compressed=(fmt == "laz"))
    finally:
        remove(tmp)
    return int(sum(written))


def _export_remote(store: PointStore, dst: str, fmt: str, mask, run, counts, part_size) -> int:
    """:func:`export_las` to a URL: parts go to a scratch prefix beside *dst*, then one task streams them
    into *dst* as one upload (:func:`stream_splice`); the scratch is removed either way."""
    import uuid

    counts, plan = _parts_plan(store, mask, run, counts, part_size)
    scratch = storage.join(storage.parent(dst), f".{storage.name(dst)}.parts-{uuid.uuid4().hex[:12]}")
    try:
        args = [(store.path, storage.join(scratch, f"part-{i:06d}.{fmt}"), fmt, mask, items, dst, i == 0)
                for i, items in enumerate(plan)]
        written = run_tasks(run, part_task, args, "export: write")
        splice_args = [([a[1] for a in args], dst, fmt == "laz")]
        # a task of its own: the driver handles no point bytes
        (run(stream_splice, splice_args, "export: assemble") if run is not None
         else [stream_splice(*a) for a in splice_args])
    finally:
        storage.remove(scratch, recursive=True)
    return int(sum(written))


def _layout(parts: list[str], compressed: bool) -> tuple[list, int, list[int], object]:
    """The parts' headers, where their points start, their counts, and the LASzip VLR (None uncompressed)."""
    from ..io.las_layout import laszip_vlr, read_header

    headers = [read_header(p) for p in parts]
    lazvlr = laszip_vlr(headers[0]) if compressed else None
    return headers, headers[0].offset_to_point_data, [int(h.point_count) for h in headers], lazvlr


def splice(parts: list[str], dst: str, *, compressed: bool) -> None:
    """Concatenate the LAS/LAZ *parts* (same header and VLRs, whole LAZ chunks but the last) into *dst*."""
    import lazrs

    from ..io.las_layout import chunk_table

    headers, start, counts, lazvlr = _layout(parts, compressed)
    h0 = headers[0]
    with open(dst, "r+b") as out:
        with open(parts[0], "rb") as src:
            out.write(src.read(start))
        if compressed:
            out.write(b"\0" * 8)  # the offset to the chunk table, written below
        table = []
        for path, h, cnt in zip(parts, headers, counts):
            with open(path, "rb") as src:
                if compressed:
                    own = chunk_table(src, start, lazvlr)
                    nchunks = -(-cnt // LAZ_CHUNK)
                    own = own[:nchunks]
                    size = sum(s for _, s in own)
                    table.extend(own)
                    pos = start + 8
                else:
                    size, pos = cnt * h.point_format.size, start
                _copy(src, out, pos, size)
        table_at = out.tell()
        if compressed:
            lazrs.write_chunk_table(out, table, lazvlr)
        evlr_at = out.tell()
        if h0.version.minor >= 4 and h0.number_of_evlrs:
            with open(parts[0], "rb") as src:
                src.seek(0, 2)
                end = src.tell()
                _copy(src, out, h0.start_of_first_evlr, end - h0.start_of_first_evlr)
        out.truncate()
        _patch_header(out, headers, counts, evlr_at)
        if compressed:
            out.seek(start)
            out.write(struct.pack("<q", table_at))


def _copy(src, out, pos: int, size: int) -> None:
    """*size* bytes of *src* from *pos* on, appended to *out* (in the kernel where it can)."""
    out.flush()
    done = 0
    try:
        while done < size:
            got = os.copy_file_range(src.fileno(), out.fileno(), size - done, pos + done)
            if got == 0:
                break
            done += got
    except (OSError, AttributeError):  # pragma: no cover - no copy_file_range: through memory
        pass
    if done < size:  # pragma: no cover
        src.seek(pos + done)
        out.seek(0, 2)
        out.write(src.read(size - done))
    out.seek(0, 2)


def _patch_header(out, headers, counts: list[int], evlr_at: int) -> None:
    """The header fields that sum or span over the parts: point counts, returns, bounds, the EVLRs' start."""
    h0 = headers[0]
    total = int(sum(counts))
    by_return = np.sum([np.asarray(h.number_of_points_by_return, dtype=np.int64) for h in headers], axis=0)
    nonempty = [h for h, c in zip(headers, counts) if c]
    maxs = np.max([h.maxs for h in nonempty], axis=0) if nonempty else np.asarray(h0.maxs)
    mins = np.min([h.mins for h in nonempty], axis=0) if nonempty else np.asarray(h0.mins)
    out.seek(0)
    raw = bytearray(out.read(h0.offset_to_point_data))
    legacy = int.from_bytes(raw[107:111], "little")
    if legacy and total < 2**32:  # laspy fills the legacy fields where they fit (formats 0-5)
        struct.pack_into("<I", raw, 107, total)
        struct.pack_into("<5I", raw, 111, *[int(v) for v in by_return[:5]])
    struct.pack_into("<6d", raw, 179, maxs[0], mins[0], maxs[1], mins[1], maxs[2], mins[2])
    if h0.version.minor >= 4:
        if h0.number_of_evlrs:
            struct.pack_into("<Q", raw, 235, evlr_at)
        struct.pack_into("<Q", raw, 247, total)
        struct.pack_into("<15Q", raw, 255, *[int(v) for v in by_return[:15]])
    out.seek(0)
    out.write(raw)


def stream_splice(parts: list[str], dst: str, compressed: bool) -> None:
    """:func:`splice` written front to back, for an upload that cannot seek: same bytes.

    Header fields and the chunk table come first from the parts' headers
    and tables; a failure discards the upload, leaving nothing at *dst*."""
    import io

    import lazrs

    from ..io.las_layout import chunk_table

    headers, start, counts, lazvlr = _layout(parts, compressed)
    h0 = headers[0]
    spans, table = [], []
    for path, h, cnt in zip(parts, headers, counts):
        if compressed:
            with storage.open_input(path, storage.HEADER_BLOCK) as src:
                own = chunk_table(src, start, lazvlr)[:-(-cnt // LAZ_CHUNK)]
            table.extend(own)
            spans.append((start + 8, sum(s for _, s in own)))
        else:
            spans.append((start, cnt * h.point_format.size))
    table_bytes = b""
    if compressed:
        buf = io.BytesIO()
        lazrs.write_chunk_table(buf, table, lazvlr)
        table_bytes = buf.getvalue()
    table_at = start + (8 if compressed else 0) + sum(size for _, size in spans)
    evlr_at = table_at + len(table_bytes)
    evlrs = b""
    if h0.version.minor >= 4 and h0.number_of_evlrs:
        first = int(h0.start_of_first_evlr)
        evlrs = storage.read_range(parts[0], first, storage.size(parts[0]) - first)
    head = io.BytesIO(storage.read_range(parts[0], 0, start))
    _patch_header(head, headers, counts, evlr_at)
    out = storage.open_output(dst)
    try:
        out.write(head.getvalue())
        if compressed:
            out.write(struct.pack("<q", table_at))
        for path, (pos, size) in zip(parts, spans):
            done = 0
            while done < size:
                step = min(storage.COPY_BLOCK, size - done)
                out.write(storage.read_range(path, pos + done, step))
                done += step
        out.write(table_bytes)
        out.write(evlrs)
    except BaseException:
        storage.discard(out)
        raise
    with storage.remote_errors(dst, writing=True):
        out.close()
