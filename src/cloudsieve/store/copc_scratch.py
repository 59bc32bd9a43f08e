"""The scratch files of a COPC export (:mod:`.copc`): a temporary folder beside a local destination, or
for a URL a prefix ``.<name>.scratch-<id>`` beside it (files written locally, uploaded whole, read by
byte ranges); removed at the end, also on failure."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from typing import BinaryIO

import numpy as np

from .. import storage
from ..atomic import make_temp_path, remove
from ..errors import CorruptInputError

__all__ = ["make_scratch", "scratch_output", "read_records", "remove_scratch"]

logger = logging.getLogger(__name__)


def make_scratch(dst: str) -> str:
    """The scratch of an export to *dst*: a new temporary folder, or for a URL an unused prefix beside it."""
    if storage.is_url(dst):
        return storage.join(storage.parent(dst), f".{storage.name(dst)}.scratch-{uuid.uuid4().hex[:12]}")
    return make_temp_path(dst, directory=True)


@contextlib.contextmanager
def scratch_output(scratch: str, name: str) -> Iterator[BinaryIO]:
    """A binary file writing scratch file *name*; for a prefix, written locally and uploaded whole."""
    if not storage.is_url(scratch):
        with open(os.path.join(scratch, name), "wb") as f:
            yield f
        return
    folder = tempfile.mkdtemp(prefix="cloudsieve-copc-")
    try:
        local = os.path.join(folder, name)
        with open(local, "wb") as f:
            yield f
        storage.upload(local, storage.join(scratch, name))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def read_records(path: str, first: int, count: int, dtype: np.dtype) -> np.ndarray:
    """*count* raw records of *dtype* of scratch file *path* from record *first* (one ranged request).

    Raises
    ------
    CorruptInputError
        The file holds fewer bytes.
    """
    size = np.dtype(dtype).itemsize
    data = storage.read_range(path, first * size, count * size)
    if len(data) != count * size:
        raise CorruptInputError(f"scratch file {path} is truncated: {count * size - len(data)} bytes missing at "
                                f"{first * size + len(data)}")
    return np.frombuffer(data, dtype=dtype)


def remove_scratch(scratch: str) -> None:
    """Remove the scratch and everything in it; errors are logged, not raised (in a ``finally``)."""
    if not storage.is_url(scratch):
        remove(scratch)
        return
    try:
        storage.remove(scratch, recursive=True)
        # s3fs does not raise for keys the store refused: look up what is left
        left = storage.isdir(scratch)
    except Exception as exc:  # noqa: BLE001 - best effort, as the local folder's removal
        logger.warning("could not remove the scratch objects under %s: %s", scratch, exc)
        return
    if left:
        logger.warning("could not remove the scratch objects under %s: some are still there", scratch)
