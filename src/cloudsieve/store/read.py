"""``read_cloud``: a whole (small) cloud, a point store or a file, in memory."""

from __future__ import annotations

import os

import numpy as np

from ..io import concatenated
from ..io import read_cloud as read_file
from ..paths import is_store
from .pointstore import PointStore

__all__ = ["read_cloud"]


def read_cloud(path: str | os.PathLike, *, format: str | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Load a whole (small) cloud into memory: a point store (:func:`cloudsieve.store.is_store`), else a file
    (:func:`cloudsieve.io.read_cloud`; *format* default: by extension). Stream large ones with
    :meth:`PointStore.chunks` or :func:`cloudsieve.io.open_reader`.

    Returns
    -------
    xyz : ndarray of shape (n, 3), float64
    attributes : dict of str to ndarray of shape (n,) or (n, k)
    """
    path = os.fspath(path)
    if not is_store(path):
        return read_file(path, format=format)
    store = PointStore.open(path)
    return concatenated([arrays for _, arrays in store.chunks()], store.dtypes)
