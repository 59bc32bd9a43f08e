"""The point store (zarr v3) and the two ways in and out of it: ingest and export."""

from .paths import local_path, same_path
from .pointstore import (
    DEFAULT_CHUNK_SIZE,
    STORE_ATTR,
    STORE_VERSION,
    Chunk,
    PointStore,
    compressors,
    delete_store,
    is_store,
)
from .ingest import ingest
from .export import export

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
]
