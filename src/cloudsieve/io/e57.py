"""E57 (ASTM E2807) terrestrial scans through pye57 (optional: ``pip install pye57``); read-only.

Every ``data3D`` scan is read in turn, its pose applied, spherical
coordinates converted, into one cloud. libE57's compressed-vector reader is
driven with ``chunk_size`` buffers (pye57's ``read_scan`` loads a whole
scan), so memory is bounded. Attributes keep their E57 names and pye57's
types; fields without a pye57 buffer type are skipped (logged); points
flagged by ``cartesianInvalidState`` are kept with the flag. Images are ignored.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..errors import CorruptInputError, InputFormatError, MissingDependencyError
from ..chunk import DEFAULT_CHUNK_SIZE
from ._base import Reader

__all__ = ["E57Reader"]

logger = logging.getLogger(__name__)

_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")


def _pye57():
    try:
        import pye57
    except ImportError as exc:  # pragma: no cover - pye57 is in the test extra
        raise MissingDependencyError(
            "reading E57 needs the optional package pye57: pip install 'cloudsieve[e57]' (or pip install pye57)"
        ) from exc
    return pye57


def _rotation_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = (float(v) for v in q)
    n = w * w + x * x + y * y + z * z
    if n == 0:
        return np.eye(3)
    s = 2.0 / n
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )


class E57Reader(Reader):
    """Chunked reader of every scan of an E57 file (see the module docstring)."""

    def __init__(self, path: str, format: str, chunk_size: int = DEFAULT_CHUNK_SIZE, **options: Any) -> None:
        super().__init__(path, format, chunk_size, **options)
        pye57 = _pye57()
        from pye57.e57 import SUPPORTED_POINT_FIELDS

        try:
            self._e57 = pye57.E57(path)
            scans = [self._e57.get_header(i) for i in range(self._e57.scan_count)]
        except Exception as exc:
            raise CorruptInputError(f"{path}: not a valid E57 file ({exc})") from exc
        self._scans = scans
        fields: list[str] | None = None
        info = []
        for i, h in enumerate(scans):
            names = list(h.point_fields)
            if not (all(c in names for c in _CARTESIAN) or all(c in names for c in _SPHERICAL)):
                raise InputFormatError(f"{path}: E57 scan {i} has neither cartesianX/Y/Z nor spherical coordinates")
            attrs = [n for n in names if n not in _CARTESIAN and n not in _SPHERICAL]
            skipped = [n for n in attrs if n not in SUPPORTED_POINT_FIELDS]
            if skipped:
                logger.warning("%s: scan %d: skipping E57 fields pye57 cannot read: %s", path, i, ", ".join(skipped))
            attrs = [n for n in attrs if n in SUPPORTED_POINT_FIELDS]
            fields = attrs if fields is None else [n for n in fields if n in attrs]
            pose = {}
            if h.has_pose():
                pose = {"rotation": np.asarray(h.rotation, float).tolist(), "translation": np.asarray(h.translation, float).tolist()}
            info.append({"name": str(getattr(h, "name", "")), "point_count": int(h.point_count), "fields": names, "pose": pose})
        self._fields = fields or []
        for name in self._fields:
            self.dtypes[name] = (np.dtype(SUPPORTED_POINT_FIELDS[name]), ())
        self.count = int(sum(h.point_count for h in scans))
        self.header = {"scans": info, "scan_count": len(scans)}

    def _read_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Blocks of at most ``chunk_size`` points, scan after scan, as dicts."""
        for i, h in enumerate(self._scans):
            yield from self._scan_chunks(i, h)

    def _scan_chunks(self, index: int, h: Any) -> Iterator[dict[str, np.ndarray]]:
        names = list(h.point_fields)
        coords = _CARTESIAN if all(c in names for c in _CARTESIAN) else _SPHERICAL
        wanted = [*coords, *self._fields]
        capacity = int(min(self.chunk_size, max(h.point_count, 1)))
        try:
            data, buffers = self._e57.make_buffers(wanted, capacity)
            reader = h.points.reader(buffers)
        except Exception as exc:
            raise CorruptInputError(f"{self.path}: cannot read E57 scan {index} ({exc})") from exc
        rotation = _rotation_matrix(np.asarray(h.rotation)) if h.has_pose() else None
        translation = np.asarray(h.translation, float) if h.has_pose() else None
        done = 0
        try:
            while True:
                try:
                    n = reader.read()
                except Exception as exc:
                    raise CorruptInputError(
                        f"{self.path}: cannot decode E57 scan {index} after point {done} ({exc}); truncated or corrupt"
                    ) from exc
                if n == 0:
                    break
                a, b, c = (np.asarray(data[k][:n], dtype=np.float64) for k in coords)
                if coords is _SPHERICAL:  # range, azimuth, elevation -> x, y, z
                    a, b, c = a * np.cos(c) * np.cos(b), a * np.cos(c) * np.sin(b), a * np.sin(c)
                xyz = np.column_stack([a, b, c])
                if rotation is not None:
                    xyz = xyz @ rotation.T + translation
                chunk = {"xyz": np.ascontiguousarray(xyz)}
                for name in self._fields:
                    chunk[name] = data[name][:n].copy()
                done += n
                yield chunk
        finally:
            reader.close()
        if done != h.point_count:
            raise CorruptInputError(f"{self.path}: E57 scan {index} says {h.point_count} points but {done} could be read")

    def close(self) -> None:
        e57 = getattr(self, "_e57", None)
        if e57 is not None:
            try:
                e57.close()
            except Exception:  # pragma: no cover
                pass
            self._e57 = None
