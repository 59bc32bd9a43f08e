"""Point-level errors between an original cloud and its simplification.

**forward** (original -> simplified): each original point's distance to the
nearest simplified point; **backward**: each simplified point's distance to
the nearest original point (zero for a subset). Hausdorff is the larger
maximum; figures in cloud units and % of the original's diagonal.

The original is streamed; per-chunk partials (:mod:`.distances`) are
combined in the driver or as dask tasks, independent of chunk size and
scheduler. Backward searches again, in a second streamed pass, only the
points not matched exactly. ``sample=N``: N points per direction, 95%
confidence intervals for mean and RMS, the max a lower bound.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..engine.calls import imap
from ..errors import EmptyInputError, InvalidParameterError, NotASubsetError
from ..io.las_records import decode_xyz
from ..params import check
from ..progress import callback
from ..store import DEFAULT_CHUNK_SIZE
from ._source import Source, open_source
from .distances import (
    HIST_PER_DECADE,
    ExactIndex,
    Target,
    aggregate,
    combine,
    forward_chunk,
    hist_edges,
    stats_partial,
)
from .planes import D2_SAMPLE, K_NORMALS, backward_chunk
from .tiles import sample_indices

logger = logging.getLogger(__name__)

__all__ = ["PointLevel", "point_errors"]


def _select(sorted_idx: np.ndarray | None, start: int, stop: int) -> np.ndarray | None:
    if sorted_idx is None:
        return None
    a, b = np.searchsorted(sorted_idx, [start, stop])
    return sorted_idx[a:b] - start


def quantise(xyz: np.ndarray, grid: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """*xyz* as a LAS file of *grid* = (scales, offsets) stores and reads it back (None: unchanged)."""
    if grid is None:
        return xyz
    scales, offsets = grid
    return decode_xyz(np.round((xyz - offsets) / scales), scales, offsets)


def _excess_copies(src: Source, bpoints: np.ndarray, rows: np.ndarray,
                   grid: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Multiplicities of the simplified points *rows* found at distance 0 but not matched (copies).
    Returns ``(points (q, 3), held (q,), original (q,))``: the distinct points and how often the simplified cloud
    and the original (on *grid*, :func:`quantise`) hold each; a subset holds none more often."""
    q = np.unique(bpoints[rows], axis=0)
    index = ExactIndex(q)
    hit, idx = index.lookup(bpoints)
    held = np.bincount(idx[hit], minlength=len(q)).astype(np.int64)
    orig = np.zeros(len(q), dtype=np.int64)
    for chunk in src.chunks():
        hit, idx = index.lookup(quantise(chunk.xyz, grid))
        orig += np.bincount(idx[hit], minlength=len(q))
    return q, held, orig


@dataclass(frozen=True)
class PointLevel:
    """What the point level measures (:func:`point_errors`); every field as there."""

    sample: int | None = None
    seed: int = 0
    chunk_size: int = DEFAULT_CHUNK_SIZE
    subset: bool = False
    error_points: int = 0
    d2_k: int | None = K_NORMALS
    d2_sample: int | None = D2_SAMPLE
    keep_sample: int = 0


def point_errors(original: Any, simplified: np.ndarray, level: PointLevel = PointLevel(), *, client: Any = None,
                 on_error_points=None, progress=None, grid: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Point-level errors of *simplified* (m, 3) against *original* (streamed: array, store, path or Source).

    *level* holds the options as in :func:`cloudsieve.evaluate.evaluate`
    (``subset`` raises NotASubsetError; ``d2_k`` None: D1 only;
    ``error_points`` sends sampled forward errors to *on_error_points*
    ``(xyz (k, 3), error (k,) float32)`` chunk by chunk; ``keep_sample``
    returns ``uniform_sample`` as :func:`.tiles.uniform_sample` draws it).
    *grid* (scales, offsets): the LAS quantisation of *simplified*, on which
    a point still counts as an original one. *progress* gets points read.

    Returns ``forward``, ``backward`` (:func:`.distances.aggregate`),
    ``hausdorff``, ``hausdorff_pct``, ``diagonal``, ``bounds``,
    ``original_count``, ``simplified_count``, ``mode``, ``sample``, ``seed``,
    ``subset``, ``not_in_original``, ``histogram``.
    """
    sample, seed, subset, error_points = level.sample, level.seed, level.subset, level.error_points
    d2_k, d2_sample, keep_sample = level.d2_k, level.d2_sample, level.keep_sample
    src: Source = open_source(original, chunk_size=level.chunk_size)
    simplified = np.ascontiguousarray(simplified, dtype=np.float64)
    if simplified.ndim != 2 or simplified.shape[1] != 3:
        raise InvalidParameterError(f"simplified points must have shape (m, 3), got {simplified.shape}")
    if len(simplified) == 0:
        raise EmptyInputError(f"the simplified cloud is empty (0 points); original: {src.name}")
    tick = callback(progress)
    rng = np.random.default_rng(seed)
    sampled = sample is not None
    n = src.count_points() if sampled or error_points or keep_sample else src.count
    fwd_idx = bwd_idx = None
    if sampled:
        sample = check("sample", sample)  # the option's one check (params)
        fwd_idx = sample_indices(n, sample, rng)
        bwd_idx = sample_indices(len(simplified), sample, rng)
        sampled = len(fwd_idx) < n or len(bwd_idx) < len(simplified)
    if n == 0:
        raise EmptyInputError(f"the original cloud is empty (0 points): {src.name}")
    ply_idx = None
    if error_points:
        ply_idx = sample_indices(n, int(error_points), np.random.default_rng([seed, 1]))
        if fwd_idx is not None:  # errors are known only for the sampled points
            ply_idx = fwd_idx if len(fwd_idx) <= error_points else np.sort(
                np.random.default_rng([seed, 1]).choice(fwd_idx, int(error_points), replace=False))

    d2_idx = None  # the forward D2 sample: global rows of the original (a subset of fwd_idx when sampled)
    if d2_k is not None and d2_sample is not None and n is not None:
        rows = fwd_idx
        if (n if rows is None else len(rows)) > d2_sample:
            d2rng = np.random.default_rng([seed, 2])
            d2_idx = (sample_indices(n, int(d2_sample), d2rng) if rows is None
                      else np.sort(d2rng.choice(rows, int(d2_sample), replace=False)))

    keep_idx = sample_indices(n, int(keep_sample), np.random.default_rng(seed)) if keep_sample else None
    kept_parts: list[np.ndarray] = []

    target = Target(simplified)
    bpoints = simplified if bwd_idx is None else simplified[bwd_idx]
    bindex = None if bwd_idx is None else ExactIndex(bpoints)
    nb = len(bpoints)
    logger.info("point errors: %s original points (%s), %d simplified, %s", n, src.name, len(simplified),
                f"sample {sample}" if sampled else "exact")

    def items():
        for chunk in src.chunks():
            start, stop = chunk.start, chunk.stop
            if keep_idx is not None:
                kept_parts.append(chunk.xyz[_select(keep_idx, start, stop)])
            select, d2_rows = _select(fwd_idx, start, stop), _select(d2_idx, start, stop)
            if select is not None and d2_rows is not None:  # positions among the sampled rows
                d2_rows = np.searchsorted(select, d2_rows)
            kw = {"select": select, "keep": _select(ply_idx, start, stop), "n_backward": nb,
                  "normals": chunk.arrays.get("normals"), "d2_k": d2_k, "d2_rows": d2_rows}
            yield (chunk.xyz,), kw

    partials = []
    for part, ply in imap(forward_chunk, items(), client, shared=(target,), kwargs={"backward_index": bindex}):
        partials.append(part)
        if len(partials) > 16:
            partials = [combine(partials)]
        if ply is not None and on_error_points is not None and len(ply[0]):
            on_error_points(*ply)
        tick(part["seen"])
    total = combine(partials)
    if n is None:  # unknown count (XYZ text) and nothing sampled: counted on the way
        n = int(total["seen"])
    if total["bbox"] is None:
        raise EmptyInputError(f"the original cloud is empty (0 points): {src.name}")
    bounds = total["bbox"]
    diagonal = float(np.linalg.norm(bounds[1] - bounds[0]))
    forward = aggregate(total, diagonal, population=n if sampled else None)

    # backward: simplified points found exactly in the original have distance 0
    matched = np.unpackbits(total["matched"], count=nb).astype(bool)
    bd, bd2 = np.zeros(nb), np.zeros(nb)
    todo = np.flatnonzero(~matched)
    d2_mask = None  # the backward D2 sample
    if d2_k is not None and d2_sample is not None and nb > d2_sample:
        d2_mask = np.zeros(nb, bool)
        d2_mask[sample_indices(nb, int(d2_sample), np.random.default_rng([seed, 3]))] = True
    if len(todo):
        logger.info("backward: %d of %d simplified points not found exactly; searching the original", len(todo), nb)
        pts = bpoints[todo]
        best, best2 = np.full(len(todo), np.inf), np.zeros(len(todo))
        sub_mask = None if d2_mask is None else d2_mask[todo]
        items2 = (((chunk.xyz,), {"normals": chunk.arrays.get("normals"), "k": d2_k, "d2_mask": sub_mask})
                  for chunk in src.chunks())
        for d, d2 in imap(backward_chunk, items2, client, shared=(pts, best)):
            win = d < best
            best[win], best2[win] = d[win], d2[win]
        bd[todo] = best
        bd2[todo] = best2
    far = todo[bd[todo] > 0]
    n_out, example = len(far), (f"e.g. {bpoints[far[0]].tolist()}, {bd[far[0]]:.6g} away" if len(far) else "")
    if grid is not None and len(far):  # original points as the simplified cloud's LAS grid stores them
        q, held, orig = _excess_copies(src, bpoints, far, grid)
        excess = np.maximum(held - orig, 0)
        n_out = int(excess.sum())
        off = far[np.isin(far, np.flatnonzero(ExactIndex(q[excess > 0]).lookup(bpoints)[0]))] if n_out else far[:0]
        example = f"e.g. {bpoints[off[0]].tolist()}, {bd[off[0]]:.6g} away" if len(off) else ""
    if len(far) < len(todo):  # exact copies held more often than one match each: count multiplicities
        q, held, orig = _excess_copies(src, bpoints, todo[bd[todo] == 0])
        excess = np.maximum(held - orig, 0)
        n_out += int(excess.sum())
        if not example and excess.any():
            j = int(np.flatnonzero(excess)[0])
            example = (f"e.g. {q[j].tolist()} held {held[j]} times, the original holds it {orig[j]} "
                       f"time{'' if orig[j] == 1 else 's'}")
    if subset and n_out:
        raise NotASubsetError(
            f"{n_out} of {nb} {'sampled ' if bwd_idx is not None else ''}simplified points are not points of "
            f"the original {src.name} ({example}), but a subset was claimed")
    bpart = stats_partial(bd, bpoints, 0)
    bsq = bd2 if d2_mask is None else bd2[d2_mask]
    bpart["d2sq"], bpart["d2sq2"], bpart["d2_count"] = float(bsq.sum()), float(np.dot(bsq, bsq)), int(len(bsq))
    backward = aggregate(bpart, diagonal, population=len(simplified) if bwd_idx is not None and nb < len(simplified) else None)
    haus = max(forward["max"], backward["max"])
    fh, bh = total["hist"], bpart["hist"]
    nz = np.flatnonzero((fh + bh) > 0)
    lo, hi = (int(nz[0]), int(nz[-1]) + 1) if len(nz) else (0, 0)
    edges = np.log10(hist_edges())
    out = {} if keep_idx is None else {"uniform_sample": np.concatenate(kept_parts) if kept_parts else np.zeros((0, 3))}
    return {
        **out,
        "mode": "sampled" if sampled else "exact",
        "sample": int(sample) if sampled else None,
        "seed": int(seed),
        "original": src.name,
        "original_count": int(n),
        "simplified_count": int(len(simplified)),
        "bounds": bounds.tolist(),
        "diagonal": diagonal,
        "forward": forward,
        "backward": backward,
        "hausdorff": haus,
        "hausdorff_pct": haus * 100.0 / diagonal if diagonal > 0 else float("nan"),
        "hausdorff_is_lower_bound": bool(sampled),
        "normals": "file" if src.has_normals else "estimated",
        "k_normals": d2_k,
        "subset": bool(n_out == 0),
        "not_in_original": int(n_out),
        "histogram": {
            "log10_edges": [float(edges[lo]), float(edges[hi])] if hi > lo else [],
            "forward": fh[lo:hi].tolist(),
            "backward": bh[lo:hi].tolist(),
            "forward_zeros": int(total["zeros"]),
            "backward_zeros": int(bpart["zeros"]),
            "per_decade": HIST_PER_DECADE,
        },
    }
