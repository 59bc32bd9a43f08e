"""The point store (zarr v3) and the ways in and out of it: ingest, export, read_cloud."""

from .chunk import DEFAULT_CHUNK_SIZE, Chunk
from ..paths import local_path, same_path
from .pointstore import (
    STORE_ATTR,
    STORE_VERSION,
    PointStore,
    compressors,
    delete_store,
    is_store,
)
from .ingest import ingest
from .export import export
from .read import read_cloud

__all__ = [
    "PointStore",
    "Chunk",
    "STORE_ATTR",
    "STORE_VERSION",
    "DEFAULT_CHUNK_SIZE",
    "compressors",
    "is_store",
    "delete_store",
    "local_path",
    "same_path",
    "ingest",
    "export",
    "read_cloud",
]
