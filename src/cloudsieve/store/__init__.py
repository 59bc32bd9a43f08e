"""The point store (zarr v3) and the ways in and out of it; names import at first use (PEP 562), so a run
without a store (:mod:`cloudsieve.engine.small`) imports no zarr."""

from __future__ import annotations

from ..lazy import keep_functions, lazy_names

#: where each public name lives (a module of this package, or ``cloudsieve.paths``)
_LAZY = {
    "DEFAULT_CHUNK_SIZE": ".chunk", "Chunk": ".chunk",
    "local_path": "..paths", "same_path": "..paths", "is_store": "..paths", "delete_store": "..paths",
    "STORE_ATTR": ".pointstore", "STORE_VERSION": ".pointstore", "PointStore": ".pointstore",
    "compressors": ".pointstore",
    "ingest": ".ingest", "export": ".export", "read_cloud": ".read",
}

__all__ = list(_LAZY)


__getattr__, __dir__ = lazy_names(__name__, _LAZY)

# ingest and export are always the functions, never the modules of the same name
keep_functions(__name__, __getattr__, {"ingest": "ingest", "export": "export"})
