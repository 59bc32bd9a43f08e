"""Points with NaN or infinite coordinates: refused (the default) or dropped, chunk by chunk.

Every reader of a file's points (ingest, and so simplify and the pipelines;
evaluate; compare) goes through :class:`ValidPoints`, for one message and
one way to drop (``drop_invalid=True``, ``--drop-invalid``).

>>> import numpy as np
>>> from cloudsieve.io.valid import ValidPoints
>>> from cloudsieve.store import Chunk
>>> valid = ValidPoints("scan.xyz", drop_invalid=True)
>>> xyz = np.array([[0.0, 0, 0], [np.nan, 0, 0], [1, 1, 1]])
>>> [c.xyz.tolist() for c in valid.chunks([Chunk(0, {"xyz": xyz})])]
[[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]]
>>> valid.invalid, valid.kept
(1, 2)
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from ..errors import EmptyInputError, InvalidPointsError
from ..chunk import Chunk

__all__ = ["ValidPoints"]

logger = logging.getLogger(__name__)


class ValidPoints:
    """Refuse or drop the points of *path* whose coordinates are NaN or infinite.
    *drop_invalid* drops them (their count logged as a warning, unless not *warn*) instead of refusing the file.
    Attributes: ``read`` (points read), ``invalid``, ``first_invalid`` (index of the first), ``kept``."""

    def __init__(self, path: str, drop_invalid: bool = False, warn: bool = True) -> None:
        self.path = str(path)
        self.drop_invalid = bool(drop_invalid)
        self.warn = bool(warn)
        self.read = 0
        self.invalid = 0
        self.first_invalid: int | None = None
        self.kept = 0

    def chunks(self, chunks: Iterable[Chunk], progress: Callable[[int], None] | None = None) -> Iterator[Chunk]:
        """The chunks of *chunks* with their valid points only, numbered from 0 without gaps; empty ones skipped.
        Without *drop_invalid*, the first invalid point stops the output and the rest is only counted. *progress*
        gets the points read per chunk. At the end, raises InvalidPointsError (invalid points, not dropped) or
        EmptyInputError (every point dropped)."""
        for _, arrays in chunks:
            xyz = arrays["xyz"]
            n = len(xyz)
            if not np.isfinite(xyz).all():  # the usual case is one flat reduction
                finite = np.isfinite(xyz).all(axis=1)
                if self.first_invalid is None:
                    self.first_invalid = self.read + int(np.argmin(finite))
                self.invalid += n - int(np.count_nonzero(finite))
                if self.drop_invalid:
                    arrays = {k: v[finite] for k, v in arrays.items()}
            self.read += n
            if progress is not None:
                progress(n)
            if self.invalid and not self.drop_invalid:
                continue  # keep counting, to name how many
            m = len(arrays["xyz"])
            if m:
                yield Chunk(self.kept, arrays)
                self.kept += m
        if self.invalid and not self.drop_invalid:
            raise InvalidPointsError(
                f"{self.path}: {self.invalid} of {self.read} points have NaN or infinite coordinates "
                f"(first: point {self.first_invalid}); pass drop_invalid=True to drop them",
                advice={"drop_invalid": True},
            )
        if self.read and not self.kept:
            raise EmptyInputError(
                f"{self.path} holds no valid points: all {self.read} have NaN or infinite coordinates")
        if self.invalid and self.warn:
            logger.warning("%s: dropped %d points with NaN or infinite coordinates", self.path, self.invalid)
