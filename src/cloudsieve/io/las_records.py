"""LAS/LAZ/COPC records piece by piece (:func:`read_pieces`), coordinate decoding (:func:`decode_xyz`)
and a record's raw attribute values (:func:`record_arrays`).

Every reader of LAS integers decodes with :func:`decode_xyz`. :func:`read_pieces` serves both an
ingest task (:mod:`cloudsieve.store.ingest_las`) and a small input's in-memory run
(:mod:`cloudsieve.engine.small`), so both hold the same integers. No zarr.
"""

from __future__ import annotations

import threading
from functools import partial

import numpy as np

from .. import storage
from ..errors import CorruptInputError, InputFormatError

__all__ = ["read_pieces", "decode_xyz", "record_arrays", "raw_values"]

_INT32 = (-(2**31), 2**31 - 1)
#: a read of at least this many points on every core (``parallel``) runs the attributes on threads
THREADED_POINTS = 1_000_000


def decode_xyz(raw, scale: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Coordinates (n, 3) float64 of the LAS integers *raw* ((n, 3) or three columns): ``X * scale + offset``."""
    cols = [raw[:, i] for i in range(3)] if isinstance(raw, np.ndarray) else list(raw)
    out = np.empty((len(cols[0]), 3), dtype=np.float64)
    for i in range(3):  # per column: a 1-D multiply-add, no (n, 3) temporaries
        np.multiply(cols[i], scale[i], out=out[:, i])
        out[:, i] += offset[i]
    return out


def raw_values(values) -> np.ndarray:
    """Raw numpy values of a laspy dimension view (sub-field or scaled)."""
    from laspy.point.dims import ScaledArrayView

    if isinstance(values, ScaledArrayView):
        values = values.array
    return np.ascontiguousarray(np.asarray(values))


def record_arrays(points, names: list[str]) -> dict[str, np.ndarray]:
    """The attributes *names* of a laspy point record, each as its raw values (bit fields unpacked)."""
    array = points.array
    out = {}
    for name in names:
        if name in array.dtype.names:
            out[name] = np.ascontiguousarray(array[name])
        else:
            out[name] = raw_values(points[name])
    return out


def read_pieces(pieces: list[tuple], names: list[str], parallel: bool = False,
                decode: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, dict, np.ndarray, np.ndarray]:
    """The records of *pieces* (:meth:`.las_plan.LasPlan.tasks`: ``(path, first, n, factors)``), in order.

    *names*: the attributes read; *parallel*: decode LAZ on every core;
    *decode* (scale, offset): return float64 coordinates as :func:`decode_xyz`
    instead of the integers.

    Returns ``(xyz (n, 3) int32 or float64, attributes, lo (3,), hi (3,))``,
    xyz in the cloud's scale and offset, lo/hi the integers' extremes.
    Raises CorruptInputError or InputFormatError.
    """
    from ..core.kernels.records import first_call, las_xyz
    from ..core.kernels.threads import Chunks

    total = sum(int(n) for _, _, n, _ in pieces)
    if decode is None:
        scale, offset = np.zeros(3), np.zeros(3)
    else:
        scale, offset = np.asarray(decode[0], dtype=np.float64), np.asarray(decode[1], dtype=np.float64)
    ints = np.empty((0 if decode else total, 3), dtype=np.int32)
    coords = np.empty((total if decode else 0, 3), dtype=np.float64)
    # the attributes beside X, Y, Z on threads (both release the GIL), numba's first call while the LAZ decodes;
    # not for a small input, whose run is mostly Python's (threads slow it down)
    threads = 2 if parallel and total >= THREADED_POINTS else 1
    if threads > 1:
        threading.Thread(target=first_call, daemon=True, name="cloudsieve-first-call").start()
    parts, mins, maxs = [], [], []
    at = 0
    with Chunks(threads) as chunks:
        for path, first, n, factors in pieces:
            rec, offs, points = _read_piece(path, int(first), int(n), parallel)
            mult, add = np.asarray(factors, dtype=np.int64)  # exact: integer factors (see las_plan)
            lo, hi = np.full(3, np.iinfo(np.int64).max), np.full(3, np.iinfo(np.int64).min)
            end = at + int(n)
            jobs = [partial(las_xyz, rec, offs, mult, add, scale, offset, ints[at:end], coords[at:end], 0, int(n),
                            lo, hi)]
            jobs += [partial(lambda name: record_arrays(points, [name])[name], name) for name in names]
            parts.append(dict(zip(names, chunks.each(lambda job: job(), jobs)[1:])))  # [0]: X, Y, Z
            at = end
            mins.append(lo)
            maxs.append(hi)
            if np.any(lo < _INT32[0]) or np.any(hi > _INT32[1]):
                raise InputFormatError(f"{path}: re-quantised to the cloud's scale and offset, its coordinates do "
                                       f"not fit LAS int32 (points {first} to {first + n - 1})")
    block = {name: parts[0][name] if len(parts) == 1 else np.concatenate([p[name] for p in parts]) for name in names}
    return coords if decode else ints, block, np.min(mins, axis=0), np.max(maxs, axis=0)


def _read_piece(path: str, first: int, n: int, parallel: bool) -> tuple[np.ndarray, np.ndarray, object]:
    """Points ``first .. first + n - 1`` of the LAS/LAZ file *path*: the records (n, size) uint8, the byte
    offsets (3,) of X, Y, Z in a record, and laspy's record (LAZ decoded on every core when *parallel*)."""
    import laspy

    from .las_checks import QUIET_READS, decode_error

    # one thread per task when tasks are the parallelism (lazrs' parallel decoder would oversubscribe)
    backend = laspy.LazBackend.LazrsParallel if parallel else laspy.LazBackend.Lazrs
    # a URL is read by ranged requests: the header and the chunk table (small reads), then this piece's chunks
    fh = storage.open_input(path, storage.HEADER_BLOCK)
    with laspy.open(fh, laz_backend=backend, closefd=True) as reader:
        storage.widen(fh)
        try:
            with QUIET_READS.reading():
                _seek(reader, first)
                points = reader.read_points(n)
        except Exception as exc:
            h = reader.header
            raise decode_error(path, int(h.point_count), h.are_points_compressed, first, first + n - 1, exc) from exc
    if len(points) != n:
        raise CorruptInputError(f"{path}: the header says {first + n} points or more but only {first + len(points)} "
                                f"could be read (truncated or corrupt)")
    array = np.ascontiguousarray(points.array)
    offs = np.array([array.dtype.fields[dim][1] for dim in ("X", "Y", "Z")], dtype=np.int64)
    return array.view(np.uint8).reshape(n, array.dtype.itemsize), offs, points


def _seek(reader, first: int) -> None:
    """Move *reader* to point *first*: LAZ with fixed-size chunks through the chunk table (decoding from the
    chunk's start only); variable-size chunks (COPC) by decoding and dropping the points before, in blocks."""
    if not first:
        return
    from .las_layout import laszip_vlr

    vlr = laszip_vlr(reader.header)
    if vlr is None or not vlr.uses_variable_size_chunks():
        reader.seek(first)
        return
    left = first
    while left:
        got = len(reader.read_points(min(left, 1_000_000)))
        if got == 0:
            raise EOFError(f"the file ends before point {first}")
        left -= got
