"""The codecs of the point store's arrays (bytes and CPU: docs/benchmarks.md, "Ingest and export")."""

from __future__ import annotations

import zarr

__all__ = ["compressors", "filters", "record_compressors"]


def compressors(kind: str = "work") -> tuple:
    """The codecs of the store's arrays: *kind* "input" (the ingested attributes) or "work" (derived arrays).

    Input arrays, written once and read by every stage: zstd(3) + bit
    shuffle (smaller than lz4 at similar decompression speed). Work arrays,
    written and read once or twice: lz4 + byte shuffle, the cheapest.
    """
    if kind == "input":
        return (zarr.codecs.BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle"),)
    return (zarr.codecs.BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),)


def filters(per_point_dims: int) -> tuple:
    """The array-to-array codecs of an input array with *per_point_dims* dimensions after the point axis.

    An (N, k) array (xyz) is stored transposed, axis after axis in each
    chunk: fewer bytes for the same CPU.
    """
    return (zarr.codecs.TransposeCodec(order=(1, 0)),) if per_point_dims == 1 else ()


def record_compressors(itemsize: int, local: bool = False) -> tuple:
    """The codecs of a work array of packed records (uint8 rows of *itemsize* bytes): lz4 with a bit shuffle
    over whole records, so each field's bytes compress together (a byte shuffle of single bytes does nothing).
    *local*: a scratch on a local disk, written and read once: stored as it is (blosc level 0, a copy), the
    codecs' CPU saved where the bytes cost no request."""
    if local:
        return (zarr.codecs.BloscCodec(cname="lz4", clevel=0, shuffle="noshuffle", typesize=1),)
    return (zarr.codecs.BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle", typesize=int(itemsize)),)
