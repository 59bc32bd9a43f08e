"""The point store (zarr v3) and the two ways in and out of it: ingest and export."""

from .convert import export, ingest
from .pointstore import STORE_ATTR, STORE_VERSION, PointStore, compressors, local_path

__all__ = ["PointStore", "STORE_ATTR", "STORE_VERSION", "compressors", "local_path", "ingest", "export"]
