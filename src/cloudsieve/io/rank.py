"""The rank dimension of LAS/LAZ outputs: ``cloudsieve_rank``, written by ``simplify --rank``, cut by ``export --keep-rank``.

A point's rank (uint64, 0 = the most important) orders the points of a run's
outputs so that the first N_k ranks are output k exactly (the nested outputs
of :mod:`cloudsieve.engine.levels`; one output: its kept points). Between two
outputs' counts, and below the last, the ranks go level by level down an
octree (the first output's bounding cube, 21 levels): a point's level is the
first at which it is the first point (lowest Morton code, then row) of its
node among the points of its band, so the points of levels <= d are one point
per occupied node of level d, as in a level of detail. Within a level the
nodes go by their Morton code with its bits reversed (their octant in the
parent first), so a cut inside a level takes from every parent alike. So::

    rank = the position of (-outputs holding the point, octree level, reversed node code, row)

in ascending order. :func:`write_ranks` holds the outputs in memory;
:func:`cut_rank` streams.
"""

from __future__ import annotations

import os

import numpy as np

from ..atomic import replacing
from ..errors import InputFormatError, NotASubsetError
from ..paths import refuse_source

__all__ = ["RANK_DIM", "morton", "octree_levels", "rank_order", "nested_rows", "write_ranks", "cut_rank"]

#: the extra bytes dimension holding the rank
RANK_DIM = "cloudsieve_rank"
_BITS = 21  # Morton bits an axis: 63 in all


def morton(xyz: np.ndarray) -> np.ndarray:
    """The Morton code (n,) uint64 of *xyz* (n, 3) on a 2^21 grid over its bounding cube (bit 3b + a: bit b of axis a)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if not len(xyz):
        return np.zeros(0, dtype=np.uint64)
    lo = xyz.min(axis=0)
    span = float((xyz.max(axis=0) - lo).max()) or 1.0
    q = np.minimum(((xyz - lo) / span * (1 << _BITS)).astype(np.uint64), np.uint64((1 << _BITS) - 1))
    code = np.zeros(len(xyz), dtype=np.uint64)
    for bit in range(_BITS):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return code


def _reversed(code: np.ndarray) -> np.ndarray:
    """The 63 bits of *code* (n,) uint64 in reverse order."""
    out = np.zeros_like(code)
    for bit in range(3 * _BITS):
        out |= ((code >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * _BITS - 1 - bit)
    return out


def octree_levels(code: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Each point's octree level (n,) int64: the first level (0 the root .. 21, 22 past the finest) at which it is
    the first of its node among the points of its *band* (n,), by Morton *code* (n,) then row."""
    n = len(code)
    order = np.lexsort((np.arange(n), code, band))
    c, b = code[order], band[order]
    differ = c[1:] ^ c[:-1]
    top = np.full(n - 1 if n else 0, -1, dtype=np.int64)  # the highest group of 3 bits that differs
    for group in range(_BITS):
        top[(differ >> np.uint64(3 * group)) != 0] = group
    level = np.empty(n, dtype=np.int64)
    level[order] = np.r_[0, np.where(b[1:] != b[:-1], 0, np.where(top < 0, _BITS + 1, _BITS - top))][:n]
    return level


def rank_order(depth: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """The rank (n,) uint64 of points held by *depth* (n,) outputs at *xyz* (n, 3): deeper first, then
    :func:`octree_levels` within each depth, then the node's reversed Morton code, then row."""
    n = len(depth)
    band = -np.asarray(depth, dtype=np.int64)
    code = morton(xyz)
    level = octree_levels(code, band)
    bits = np.minimum(3 * level, 3 * _BITS).astype(np.uint64)
    node = _reversed(code) & ((np.uint64(1) << bits) - np.uint64(1))  # the node's code at its level, reversed
    order = np.lexsort((np.arange(n), node, level, band))
    rank = np.empty(n, dtype=np.uint64)
    rank[order] = np.arange(n, dtype=np.uint64)
    return rank


def _records(points) -> np.ndarray:
    """A LAS file's point records as rows of bytes (n, record length)."""
    array = np.ascontiguousarray(points.array)
    return array.view(np.uint8).reshape(len(array), -1)


def _row_hash(rows: np.ndarray) -> np.ndarray:
    """A 64-bit hash (n,) uint64 of each row of *rows* (n, w) uint8."""
    words = np.pad(rows, ((0, 0), (0, -rows.shape[1] % 8))).view(np.uint64)
    h = np.full(len(rows), 0x9E3779B97F4A7C15, dtype=np.uint64)
    for j in range(words.shape[1]):
        h = (h ^ words[:, j]) * np.uint64(0xFF51AFD7ED558CCD)
        h ^= h >> np.uint64(33)
    return h


def _members(ka: np.ndarray, kb: np.ndarray) -> np.ndarray:
    """Mask (n,) of the keys *ka* matched by the keys *kb*: as many of each key, the first ones, as *kb* holds."""
    order = np.argsort(ka, kind="stable")
    grouped = ka[order]
    first = np.searchsorted(grouped, grouped, side="left")  # each key's rank among its equals, in a's order
    sb = np.sort(kb)
    wanted = np.searchsorted(sb, grouped, side="right") - np.searchsorted(sb, grouped, side="left")
    member = np.zeros(len(ka), dtype=bool)
    member[order] = np.arange(len(ka)) - first < wanted
    return member


def nested_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rows of *a* (n, w) uint8 that the rows of *b* (m, w) are, in order: *b* is *a* with rows left out.

    Equal rows are matched first to first. NotASubsetError when *b* holds a row *a* lacks."""
    if len(b) == 0:
        return np.zeros(0, dtype=np.int64)
    rows = np.flatnonzero(_members(_row_hash(a), _row_hash(b)))
    if len(rows) == len(b) and np.array_equal(a[rows], b):
        return rows
    # a hash collision, or b is not nested in a: the exact match, by the rows themselves
    _, ids = np.unique(np.concatenate([a, b]), axis=0, return_inverse=True)
    ids = ids.ravel()
    member = _members(ids[: len(a)], ids[len(a):])
    rows = np.flatnonzero(member)
    if len(rows) != len(b) or not np.array_equal(a[rows], b):
        raise NotASubsetError(f"{len(b) - int(member.sum())} of {len(b)} points are not in the output before")
    return rows


def write_ranks(paths: list[str]) -> None:
    """Add :data:`RANK_DIM` to the LAS/LAZ files *paths*, each a subset of the one before in its order
    (:func:`rank_order`); each file rewritten atomically."""
    import laspy

    clouds = [laspy.read(p) for p in paths]
    index = [np.arange(len(clouds[0].points), dtype=np.int64)]  # each output's rows in the first
    depth = np.ones(len(index[0]), dtype=np.int64)
    for before, after in zip(clouds, clouds[1:]):
        index.append(index[-1][nested_rows(_records(before.points), _records(after.points))])
        depth[index[-1]] += 1
    rank = rank_order(depth, np.column_stack([clouds[0].x, clouds[0].y, clouds[0].z]))
    for path, cloud, rows in zip(paths, clouds, index):
        if RANK_DIM not in cloud.point_format.dimension_names:
            cloud.add_extra_dim(laspy.ExtraBytesParams(RANK_DIM, "uint64", description="cloudsieve keep order"))
        cloud[RANK_DIM] = rank[rows]
        with replacing(path) as tmp:
            cloud.write(tmp, do_compress=path.lower().endswith(".laz"))


def cut_rank(src: str, dst: str, keep: int, *, overwrite: bool = False, chunk_size: int = 1_000_000) -> int:
    """Write the points of *src* of rank below *keep* to *dst* (LAS/LAZ), chunk by chunk; returns their count."""
    import laspy

    from . import check_readable, check_writable

    check_readable(src)
    refuse_source(os.fspath(src), os.fspath(dst))
    fmt = check_writable(dst, None, overwrite=overwrite)
    if fmt not in ("las", "laz"):
        raise InputFormatError(f"{dst}: keep_rank writes LAS or LAZ, not {fmt}")
    written = 0
    with laspy.open(src) as reader:
        if RANK_DIM not in reader.header.point_format.dimension_names:
            raise InputFormatError(f"{src} has no {RANK_DIM} dimension: write one with cloudsieve simplify --rank")
        with replacing(os.fspath(dst)) as tmp, laspy.open(tmp, mode="w", header=reader.header,
                                                           do_compress=fmt == "laz") as writer:
            for points in reader.chunk_iterator(chunk_size):
                chosen = points[points[RANK_DIM] < np.uint64(keep)]
                writer.write_points(chosen)
                written += len(chosen)
    return written
