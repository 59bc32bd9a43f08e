"""LAS, LAZ and COPC through laspy (lazrs for compression), in chunks.

Each dimension comes out under its laspy name with its raw value (bit fields
unpacked, extra bytes unscaled), plus "xyz" = ``X * scale + offset`` float64.
The header travels as a dict (:mod:`.las_header`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import laspy
import numpy as np
from laspy.vlrs.vlrlist import VLRList

from .. import storage
from ..errors import CorruptInputError, InputFormatError, InvalidParameterError
from ..chunk import DEFAULT_CHUNK_SIZE
from ._base import Reader, Writer, logger  # the writers' logger: conversion warnings come from there
from .las_checks import QUIET_READS, check_layout, decode_error
from .las_header import build_header, clip_to_dimension, header_from_dict, header_to_dict, vlr_from_dict
from .las_records import decode_xyz, raw_values, record_arrays

__all__ = ["LasReader", "LasWriter", "LasRecords", "LasPacking", "las_sourced", "laz_backend"]

_XYZ = ("X", "Y", "Z")


def laz_backend(parallel: bool = True):
    """laspy's LAZ backends, best first; *parallel* False: lazrs on one thread first (a task that owns a core;
    the same bytes for a file of one point or more, not for an empty one)."""
    backends = laspy.LazBackend.detect_available()
    if not parallel:
        backends = tuple(b for b in backends if b != laspy.LazBackend.LazrsParallel)
    return backends if backends else None


# --------------------------------------------------------------------- reader
def _las_dtypes(header: laspy.LasHeader) -> dict:
    rec = laspy.ScaleAwarePointRecord.zeros(1, header=header)
    dtypes: dict[str, tuple[np.dtype, tuple]] = {"xyz": (np.dtype(np.float64), (3,))}
    for name in header.point_format.dimension_names:
        if name in _XYZ:
            continue
        v = raw_values(rec[name])
        dtypes[name] = (v.dtype, tuple(v.shape[1:]))
    return dtypes


class LasReader(Reader):
    """Chunked reader of LAS 1.0-1.4 / LAZ / COPC files (point formats 0-10); option ``laz_backend`` (default lazrs,
    parallel)."""

    def __init__(self, path: str, format: str, chunk_size: int = DEFAULT_CHUNK_SIZE, **options: Any) -> None:
        super().__init__(path, format, chunk_size, **options)
        backend = options.get("laz_backend", laz_backend())
        check_layout(path)
        try:
            self._las = laspy.open(storage.open_input(path, storage.HEADER_BLOCK), mode="r", laz_backend=backend,
                                   closefd=True)
        except (laspy.LaspyException, OSError, ValueError, EOFError, IndexError) as exc:
            raise CorruptInputError(f"{path}: not a valid LAS/LAZ file ({exc})") from exc
        h = self._las.header
        if h.version.major != 1 or h.version.minor > 4:
            self._las.close()
            raise CorruptInputError(f"{path}: the header says LAS version {h.version}, not 1.0 to 1.4 (corrupt header)")
        try:
            evlrs = list(self._las.evlrs or []) if h.version.minor >= 4 else []
        except Exception as exc:
            self._las.close()
            raise CorruptInputError(f"{path}: cannot read the extended VLRs ({exc}); truncated or corrupt") from exc
        self.count = int(h.point_count)
        self.header = header_to_dict(h, evlrs)
        raw = storage.read_range(path, 90, 4)  # raw creation day/year: laspy reads an unset (0/0) date as None
        self.header["creation_day_year"] = [int.from_bytes(raw[:2], "little"), int.from_bytes(raw[2:], "little")]
        self.dtypes = _las_dtypes(h)
        self._names = [n for n in self.dtypes if n != "xyz"]
        self._scales = np.asarray(h.scales, dtype=np.float64)
        self._offsets = np.asarray(h.offsets, dtype=np.float64)
        if not h.are_points_compressed:
            self._check_size(h)

    def _check_size(self, h: laspy.LasHeader) -> None:
        size = storage.size(self.path)
        end = size
        if h.version.minor >= 4 and h.number_of_evlrs > 0 and 0 < h.start_of_first_evlr <= size:
            end = h.start_of_first_evlr
        if h.version.minor >= 3 and 0 < h.start_of_waveform_data_packet_record <= end:
            end = h.start_of_waveform_data_packet_record  # internal waveform data follows the points
        psize = h.point_format.size
        start = h.offset_to_point_data
        available = max(end - start, 0) // psize
        if available < self.count:
            self.close()
            raise CorruptInputError(
                f"{self.path}: header says {self.count} points but the file holds data for only {available} "
                f"(truncated or corrupt)"
            )
        if available > self.count:
            self.close()
            raise CorruptInputError(
                f"{self.path}: header says {self.count} points but the file holds data for {available} "
                f"(header count disagrees with the data)"
            )

    def _read_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Blocks of at most ``chunk_size`` points, as dicts (see :meth:`Reader.chunks`)."""
        done = 0
        it = self._las.chunk_iterator(self.chunk_size)
        while True:
            try:
                with QUIET_READS.reading():
                    points = next(it)
            except StopIteration:
                break
            except Exception as exc:
                raise self._decode_error(done, exc) from exc
            n = len(points)
            if n == 0:
                break
            xyz = decode_xyz([points.array[dim] for dim in _XYZ], self._scales, self._offsets)
            chunk = {"xyz": xyz, **record_arrays(points, self._names)}
            done += n
            yield chunk
        if done != self.count:
            raise CorruptInputError(
                f"{self.path}: header says {self.count} points but only {done} could be read (truncated or corrupt)"
            )

    def _decode_error(self, done: int, exc: Exception) -> CorruptInputError:
        last = min(done + self.chunk_size, self.count) - 1
        return decode_error(self.path, self.count, self._las.header.are_points_compressed, done, last, exc)

    def close(self) -> None:
        las = getattr(self, "_las", None)
        if las is not None:
            las.close()
            self._las = None


# --------------------------------------------------------------------- records
def las_sourced(source_format: str | None, header: dict) -> bool:
    """Whether a cloud of *source_format* and *header* keeps its LAS header on LAS/LAZ output (every attribute
    copied as it is)."""
    return source_format in ("las", "laz", "copc") or (source_format is None and "point_format" in header)


class LasRecords:
    """Attributes -> the packed point records of *header*'s point format (``laspy.LasHeader``), as the LAS/LAZ
    writer writes them: X/Y/Z ``round((xyz - offset) / scale)``, each attribute by its *mapping* entry
    ``(name, LAS name, how)``; *label* names the file in messages."""

    def __init__(self, header: laspy.LasHeader, mapping: list, label: str) -> None:
        self.header, self.mapping, self.label = header, mapping, label
        self.scales = np.asarray(header.scales, dtype=np.float64)
        self.offsets = np.asarray(header.offsets, dtype=np.float64)
        rec = laspy.ScaleAwarePointRecord.zeros(0, header=header)
        self.packed = set(rec.array.dtype.names)
        self.las_names = set(header.point_format.dimension_names)
        self.said: set[str] = set()  # the attributes whose values did not fit a conversion (said once)

    def build(self, chunk: dict[str, np.ndarray]) -> laspy.ScaleAwarePointRecord:
        """The records of the points *chunk* ``{"xyz": (n, 3), name: (n,) ...}``."""
        xyz = np.asarray(chunk["xyz"], dtype=np.float64)
        n = len(xyz)
        rec = laspy.ScaleAwarePointRecord.zeros(n, header=self.header)
        for i, dim in enumerate(_XYZ):
            raw = _las_ints(xyz[:, i], self.offsets[i], self.scales[i])
            if raw is None:
                raise InputFormatError(
                    f"cannot write {self.label}: {'xyz'[i]} values {xyz[:, i].min()}..{xyz[:, i].max()} do not fit "
                    f"LAS int32 with scale {self.scales[i]} and offset {self.offsets[i]}"
                )
            rec.array[dim] = raw
        for name, las_name, how in self.mapping:
            if name not in chunk or las_name not in self.las_names:
                continue
            values = np.asarray(chunk[name])
            if how == "color8":
                values = values.astype(np.uint16) * np.uint16(257)
            elif how == "unit16":
                values = np.nan_to_num(values.astype(np.float64))
                if name not in self.said and len(values) and (values.min() < 0 or values.max() > 1):  # once a file
                    self.said.add(name)
                    logger.warning("%s: %s has values outside 0..1 (%g..%g): LAS %s clipped to 0..65535", self.label,
                                   name, values.min(), values.max(), las_name)
                values = np.clip(np.round(values * 65535.0), 0, 65535).astype(np.uint16)
            elif how == "int":
                dim = self.header.point_format.dimension_by_name(las_name)
                values, outside = clip_to_dimension(values, dim)
                if outside and name not in self.said:  # once a file
                    self.said.add(name)
                    logger.warning("%s: %s has values outside LAS %s's %d..%d (%d..%d): clipped", self.label, name,
                                   las_name, dim.min, dim.max, *outside)
            try:
                if las_name in self.packed:
                    rec.array[las_name] = values
                else:
                    rec[las_name] = values
            except (ValueError, OverflowError, laspy.LaspyException) as exc:
                raise InputFormatError(f"cannot write {self.label}: dimension {las_name!r}: {exc}") from exc
        return rec


class LasPacking:
    """A LAS-sourced store's packed point records, built in tasks (pickles small): :meth:`dtype` and
    ``packing(arrays) -> records`` as :class:`LasRecords` builds them for the store's *header* dict (every
    attribute of *names* copied); *label* names the output in messages."""

    def __init__(self, header: dict, names: list[str], label: str) -> None:
        self.header, self.names, self.label = header, list(names), label
        self._records: LasRecords | None = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_records": None}

    def _built(self) -> LasRecords:
        if self._records is None:
            header, _ = header_from_dict(self.header, self.label)
            self._records = LasRecords(header, [(n, n, "copy") for n in self.names if n != "xyz"], self.label)
        return self._records

    def dtype(self) -> np.dtype:
        """The records' numpy dtype (the point format's)."""
        return self._built().header.point_format.dtype()

    def __call__(self, xyz: np.ndarray, arrays: dict[str, np.ndarray], take: np.ndarray,
                 order: np.ndarray) -> np.ndarray:
        """The records of the points ``arrays[name][take]``, their coordinates ``xyz[order]`` (*xyz*: (m, 3)
        float64, *take*, *order*: (n,) int64): :meth:`LasRecords.build`'s bytes for those points, each packed
        field written once (the bit fields composed aside); values that do not fit are left to
        :meth:`LasRecords.build`, which raises."""
        built = self._built()
        points = {"xyz": xyz.take(order, axis=0), **{d: np.asarray(v).take(take, axis=0) for d, v in arrays.items()}}
        xyz = points["xyz"]
        n = len(xyz)
        rec = np.zeros(n, dtype=built.header.point_format.dtype())
        for i, dim in enumerate(_XYZ):
            raw = _las_ints(xyz[:, i], built.offsets[i], built.scales[i])
            if raw is None:
                return built.build(points).array  # which raises, naming the file
            rec[dim] = raw
        subfields = _sub_fields(built.header.point_format.id)
        bits: dict[str, np.ndarray] = {}
        for name, _, _ in built.mapping:
            if name not in points:
                continue
            values = points[name]
            if name in rec.dtype.names:
                rec[name] = values
            elif name in subfields:
                parent, field = subfields[name]
                lsb = (field.mask & -field.mask).bit_length() - 1
                if n and (values.dtype.kind not in "ub" or int(values.max()) > field.mask >> lsb):
                    return built.build(points).array
                acc = bits.setdefault(parent, np.zeros(n, dtype=rec.dtype[parent]))
                acc |= values.astype(acc.dtype) << acc.dtype.type(lsb)
        for parent, acc in bits.items():
            rec[parent] = acc
        return rec


def _las_ints(values: np.ndarray, offset: float, scale: float) -> np.ndarray | None:
    """LAS integers (int32) ``round((values - offset) / scale)``, or None where one is not finite or not in int32."""
    raw = np.round((values - offset) / scale)
    if len(raw) and (raw.min() < -(2**31) or raw.max() > 2**31 - 1 or not np.all(np.isfinite(raw))):
        return None
    return raw.astype(np.int32)


def _sub_fields(point_format_id: int) -> dict:
    """laspy's bit fields of a point format: name -> (packed field, SubField(mask))."""
    from laspy.point.dims import get_sub_fields_dict

    return get_sub_fields_dict(point_format_id)


# --------------------------------------------------------------------- writer
class LasWriter(Writer):
    """Chunked LAS/LAZ writer.
    A LAS-sourced header is carried over (:func:`.las_header.header_from_dict`); other sources get
    :func:`.las_header.build_header` (``bounds=`` sets scales and offsets). ``label=`` names the whole file in
    messages when this is a part of it."""

    def _open(self) -> None:
        self._label = self.options.get("label", self.path)  # the file named in messages (a part: its whole file)
        if las_sourced(self.source_format, self.header):
            self._header_dict = self.header
            self._mapping = [(n, n, "copy") for n in self.dtypes if n != "xyz"]
        else:
            self._header_dict, self._mapping = build_header(self.dtypes, self.options.get("bounds"), self._label)
        header, self._evlrs = header_from_dict(self._header_dict, self._label)
        if self._evlrs and header.version.minor < 4:  # pragma: no cover - EVLRs imply 1.4
            self._evlrs = []
        compress = self.format == "laz"
        try:
            self._writer = laspy.open(
                self.file,
                mode="w",
                header=header,
                do_compress=compress,
                laz_backend=self.options.get("laz_backend", laz_backend()) if compress else None,
                closefd=False,
            )
        except laspy.LaspyException as exc:
            raise InputFormatError(f"cannot write {self._label}: {exc}") from exc
        self._keep_extra_bytes_vlrs()
        self._pf = header.point_format
        self._header = header
        self._records = LasRecords(header, self._mapping, self._label)

    def _keep_extra_bytes_vlrs(self) -> None:
        """Write the source's extra-bytes VLRs verbatim (laspy regrows their min/max statistics), for a byte-exact
        round trip."""
        source = [v for v in self._header_dict.get("vlrs", []) if v["user_id"] == "LASF_Spec" and v["record_id"] == 4]
        vlrs = self._writer.header.vlrs
        positions = [i for i, v in enumerate(vlrs) if type(v).__name__ == "ExtraBytesVlr"]
        if len(source) != len(positions):
            return
        for i, d in zip(positions, source):
            vlr = vlr_from_dict(d)
            vlr.grow = lambda points: None  # keep the source statistics
            vlr.partial_reset = lambda: None
            vlrs[i] = vlr

    def _write(self, chunk: dict[str, np.ndarray]) -> None:
        self._writer.write_points(self._records.build(chunk))

    def write_records(self, records: np.ndarray) -> None:
        """Append packed point records of this file's point format (as :meth:`LasRecords.build` makes them):
        the bytes :meth:`write` writes for the same points, with no assembly here."""
        if records.dtype != self._pf.dtype():
            raise InvalidParameterError(f"cannot write {self._label}: records of dtype {records.dtype}, not point "
                                        f"format {self._pf.id}'s {self._pf.dtype()}")
        if len(records):
            self._writer.write_points(laspy.PackedPointRecord(records, self._pf))
            self.count += len(records)

    def _close(self) -> None:
        if self._evlrs:
            self._writer.write_evlrs(VLRList(self._evlrs))
        self._writer.close()
        day_year = self._header_dict.get("creation_day_year")
        if self._header_dict.get("creation_date") is None and day_year:
            # laspy writes the current date for an unset one: put the source's raw bytes back
            self.file.seek(90)
            self.file.write(int(day_year[0]).to_bytes(2, "little") + int(day_year[1]).to_bytes(2, "little"))

    def _abort_hook(self) -> None:
        try:
            self._writer.close()
        except Exception:
            pass
