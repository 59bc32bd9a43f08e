"""Points with NaN or infinite coordinates: refused (the default) or dropped, chunk by chunk.

Every way in that reads a file's points goes through :class:`ValidPoints`:
:func:`cloudsieve.store.ingest` (and so :func:`cloudsieve.simplify` and the
pipelines), :func:`cloudsieve.evaluate` and :func:`cloudsieve.compare`. So
they refuse such points with the same message, and drop them the same way
when asked (``drop_invalid=True``, ``--drop-invalid``).

Example
-------
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

    Parameters
    ----------
    path : str
        The file read (named in the messages).
    drop_invalid : bool
        Drop such points (their count is logged as a warning) instead of
        refusing the file.
    warn : bool
        Log that warning (False for a second pass over the same file).

    Attributes
    ----------
    read : int
        Points read so far (valid or not).
    invalid : int
        Points with a NaN or infinite coordinate among them.
    first_invalid : int or None
        Index in the file of the first such point.
    kept : int
        Points passed on.
    """

    def __init__(self, path: str, drop_invalid: bool = False, warn: bool = True) -> None:
        self.path = str(path)
        self.drop_invalid = bool(drop_invalid)
        self.warn = bool(warn)
        self.read = 0
        self.invalid = 0
        self.first_invalid: int | None = None
        self.kept = 0

    def chunks(self, chunks: Iterable[Chunk], progress: Callable[[int], None] | None = None) -> Iterator[Chunk]:
        """The chunks of *chunks* with their valid points only, numbered from 0 without gaps.

        Without *drop_invalid*, the first invalid point stops the points
        passed on, and the rest is read only to count the invalid ones for
        the message. *progress* is called with the points read per chunk.

        Yields
        ------
        Chunk
            ``(start, arrays)``, every array of the chunk filtered alike;
            empty chunks are skipped.

        Raises
        ------
        InvalidPointsError
            At the end, when some point is invalid and *drop_invalid* is False:
            ``"<path>: 3 of 6 points have NaN or infinite coordinates (first:
            point 1); pass drop_invalid=True to drop them"``.
        EmptyInputError
            At the end, when every point read was invalid and dropped.
        """
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
