"""The codecs of the point store's arrays, chosen by measurement."""

from __future__ import annotations

import zarr

__all__ = ["compressors"]


def compressors(kind: str = "work") -> tuple:
    """The codecs of the store's arrays: *kind* "input" (the ingested attributes) or "work" (derived arrays).

    Measured on make_scan's 1 M-point cloud (LAS point format 3, 17 arrays,
    X/Y/Z as int32; one core; LAZ is 5.68 bytes a point), bytes a point and
    CPU to compress / decompress every array: blosc lz4 + byte shuffle 12.92
    (0.18 / 0.07 s), lz4 + bit shuffle 11.40 (0.17 / 0.06 s), zstd(1) + bit
    shuffle 11.04 (0.21 / 0.08 s), zstd(3) + bit shuffle 10.26 (0.25 / 0.08
    s), zstd(5) + bit shuffle 9.52 (0.36 / 0.06 s); X/Y/Z alone 6.01 with
    lz4, 4.70 with zstd(3) (numcodecs' Delta before it: 5.16, since the
    axes interleave). The input arrays are written once and read by every
    stage: zstd(3) + bit shuffle. Derived arrays are work files written and
    read once or twice: the cheapest, lz4 + byte shuffle.
    """
    if kind == "input":
        return (zarr.codecs.BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle"),)
    return (zarr.codecs.BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),)
