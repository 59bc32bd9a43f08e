"""The scratch files of a COPC export (:mod:`.copc`): where they live, how tasks write and read them.

For a local destination, the scratch is a temporary folder beside it (the
workers reach it as they reach the store). For a URL (an object store, where
workers share no disk), it is the prefix ``.<name>.scratch-<id>`` beside the
destination: a task writes each of its scratch files in its worker's
temporary folder and uploads it whole (:func:`cloudsieve.storage.upload`);
readers fetch byte ranges (:func:`cloudsieve.storage.read_range`). Either is
removed at the end of the export, also on failure (:func:`remove_scratch`).
"""

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
    """The scratch of an export to *dst*: a new temporary folder beside a local *dst*; for a URL, a prefix
    beside it no other export uses (nothing is created until a task uploads its first file)."""
    if storage.is_url(dst):
        return storage.join(storage.parent(dst), f".{storage.name(dst)}.scratch-{uuid.uuid4().hex[:12]}")
    return make_temp_path(dst, directory=True)


@contextlib.contextmanager
def scratch_output(scratch: str, name: str) -> Iterator[BinaryIO]:
    """A binary file writing the scratch file *name*: in the local folder *scratch*; for a prefix on an object
    store, in this worker's temporary folder, uploaded to ``scratch/name`` once written whole, then removed."""
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
    """*count* raw records of *dtype* of the scratch file *path* (a local path or a URL: one ranged request)
    from record *first*.

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
    """Remove the scratch folder or prefix and everything in it; an error is logged, not raised (raised in
    a ``finally``, it would replace the export's own)."""
    if not storage.is_url(scratch):
        remove(scratch)
        return
    try:
        storage.remove(scratch, recursive=True)
        # s3fs deletes in bulk and does not raise for the keys the store refused: what is left is looked up
        left = storage.isdir(scratch)
    except Exception as exc:  # noqa: BLE001 - best effort, as the local folder's removal
        logger.warning("could not remove the scratch objects under %s: %s", scratch, exc)
        return
    if left:
        logger.warning("could not remove the scratch objects under %s: some are still there", scratch)
