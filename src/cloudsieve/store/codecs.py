"""The codecs of the point store's arrays, chosen by measurement."""

from __future__ import annotations

import zarr

__all__ = ["compressors", "filters", "record_compressors"]


def compressors(kind: str = "work") -> tuple:
    """The codecs of the store's arrays: *kind* "input" (the ingested attributes) or "work" (derived arrays).

    The input arrays are written once and read by every stage: zstd(3) +
    bit shuffle, a fifth fewer bytes than lz4 + byte shuffle for about 40%
    more compression CPU, decompressing as fast (numcodecs' Delta before it gains
    nothing: the axes interleave). Derived arrays are work files written and
    read once or twice: the cheapest, lz4 + byte shuffle. The codecs'
    bytes and CPU: docs/benchmarks.md, "Ingest and export".
    """
    if kind == "input":
        return (zarr.codecs.BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle"),)
    return (zarr.codecs.BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),)


def filters(per_point_dims: int) -> tuple:
    """The array-to-array codecs of an input array with *per_point_dims* dimensions after the point axis.

    An (N, k) array (xyz) is stored transposed, one axis after the other in
    each chunk: X/Y/Z as int32 of make_scan's 1 M-point cloud 4.70 -> 4.13
    bytes a point with zstd(3) + bit shuffle (4.86 -> 4.45 with lz4), the
    whole store 10.26 -> 9.69, for the same CPU.
    """
    return (zarr.codecs.TransposeCodec(order=(1, 0)),) if per_point_dims == 1 else ()


def record_compressors(itemsize: int) -> tuple:
    """The codecs of a work array of packed records (uint8 rows of *itemsize* bytes, export's buckets): lz4 with
    a bit shuffle over whole records, each field's bytes compressed together. Measured on make_scan's
    records (52 bytes: X/Y/Z float64 and 17 attributes, 16,384 a chunk): 33.5 bytes a record with the work
    arrays' codec (a byte shuffle of single bytes shuffles nothing), 19.9 with this, for less CPU."""
    return (zarr.codecs.BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle", typesize=int(itemsize)),)
