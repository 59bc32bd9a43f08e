"""The one chunk shape, re-exported here (its home is :mod:`cloudsieve.chunk`, outside this package, so
the readers of :mod:`cloudsieve.io` import it without zarr)."""

from ..chunk import DEFAULT_CHUNK_SIZE, Chunk

__all__ = ["Chunk", "DEFAULT_CHUNK_SIZE"]
