"""Nearest-neighbour distances of one chunk, and their chunk / combine / aggregate statistics.

The per-chunk machinery of :func:`cloudsieve.evaluate.points.point_errors`, merged in any order as dask
reductions do. Shortcuts that change no figure: kept points are found by hash lookup (distance 0); other
queries run in Morton order with a distance bound learnt from the previous chunk.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..errors import EmptyInputError
from .morton import morton_order
from .planes import d2_squares

__all__ = [
    "HIST_DECADES",
    "HIST_PER_DECADE",
    "hist_edges",
    "morton_order",
    "ExactIndex",
    "Target",
    "stats_partial",
    "forward_chunk",
    "combine",
    "aggregate",
    "d2_figures",
]

#: the error histogram's fixed log bins from 1e-12 to 1e12 (cloud units), so partials sum; zeros counted apart
HIST_DECADES = (-12, 12)
HIST_PER_DECADE = 20
_NBINS = (HIST_DECADES[1] - HIST_DECADES[0]) * HIST_PER_DECADE

_Z95 = 1.959963984540054


def hist_edges() -> np.ndarray:
    """Edges of the fixed error histogram, shape (481,), from 1e-12 to 1e12."""
    return np.logspace(HIST_DECADES[0], HIST_DECADES[1], _NBINS + 1)


def _histogram(d: np.ndarray) -> tuple[np.ndarray, int]:
    pos = d[d > 0]
    if len(pos) == 0:
        return np.zeros(_NBINS, np.int64), int(len(d))
    b = np.floor((np.log10(pos) - HIST_DECADES[0]) * HIST_PER_DECADE).astype(np.int64)
    np.clip(b, 0, _NBINS - 1, out=b)
    return np.bincount(b, minlength=_NBINS).astype(np.int64), int(len(d) - len(pos))


_H1, _H2, _H3 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9)


def _hash(points: np.ndarray) -> np.ndarray:
    u = np.ascontiguousarray(points, dtype=np.float64).view(np.uint64).reshape(-1, 3)
    with np.errstate(over="ignore"):
        return (u[:, 0] * _H1) ^ (u[:, 1] * _H2) ^ (u[:, 2] * _H3)


class ExactIndex:
    """Exact-coordinate lookup of *points* (n, 3) float64, kept by reference (hash + sorted search + verification)."""

    def __init__(self, points: np.ndarray):
        self.points = points
        h = _hash(points)
        self.order = np.argsort(h, kind="stable")
        self.keys = h[self.order]

    def lookup(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(hit (m,) bool, index (m,) int64)``: index of an identical point where hit."""
        if len(self.keys) == 0 or len(q) == 0:
            return np.zeros(len(q), bool), np.zeros(len(q), np.int64)
        h = _hash(q)
        o = np.argsort(h)  # sorted keys make searchsorted cache friendly (several times faster)
        pos = np.empty(len(h), np.int64)
        pos[o] = np.searchsorted(self.keys, h[o])
        np.minimum(pos, len(self.keys) - 1, out=pos)
        idx = self.order[pos]
        hit = self.keys[pos] == h
        if hit.any():
            w = np.flatnonzero(hit)
            hit[w] = np.all(self.points[idx[w]] == q[w], axis=1)
        return hit, idx


class Target:
    """The in-memory simplified cloud *points* (m, 3), ready for nearest-neighbour queries.
    The k-d tree is over a Morton-sorted copy; :meth:`query` returns indices into *points*. The distance bound is
    twice the previous query's 99th percentile. Picklable (sent once to dask workers)."""

    def __init__(self, points: np.ndarray):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self._perm = morton_order(self.points)
        self._tree = cKDTree(self.points[self._perm], balanced_tree=False, compact_nodes=False)
        self._exact = ExactIndex(self.points)
        self.bound: float | None = None

    def __len__(self) -> int:
        return len(self.points)

    def query(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest simplified point of each row of *q* (m, 3): ``(distance, index)``, exact."""
        d = np.zeros(len(q))
        hit, idx = self._exact.lookup(q)
        rest = np.flatnonzero(~hit)
        if len(rest):
            sub = q[rest]
            o = morton_order(sub)
            sub = sub[o]
            if self.bound is not None:  # exact: points beyond the bound are queried again without it
                dd, jj = self._tree.query(sub, k=1, workers=-1, distance_upper_bound=self.bound)
                miss = np.flatnonzero(~np.isfinite(dd))
                if len(miss):
                    dd[miss], jj[miss] = self._tree.query(sub[miss], k=1, workers=-1)
            else:
                dd, jj = self._tree.query(sub, k=1, workers=-1)
            d[rest[o]] = dd
            idx[rest[o]] = self._perm[jj]
            if len(dd) >= 1000:
                self.bound = 2.0 * float(np.quantile(dd, 0.99)) or None
        return d, idx


def _empty_partial(m: int) -> dict:
    return {
        "count": 0,
        "sum": 0.0,
        "sumsq": 0.0,
        "sum4": 0.0,
        "d2sq": 0.0,
        "d2sq2": 0.0,
        "d2_count": 0,
        "max": 0.0,
        "argmax": None,
        "zeros": 0,
        "hist": np.zeros(_NBINS, np.int64),
        "bbox": None,
        "matched": np.zeros((m + 7) // 8, np.uint8),
        "seen": 0,
    }


def stats_partial(d: np.ndarray, where: np.ndarray, m_matched: int) -> dict:
    """Partial statistics of distances *d* (n,) measured at *where* (n, 3) (a chunk kernel: input assumed valid).
    Returns the partial of :func:`forward_chunk` with an all-zero ``matched`` bitmask of length *m_matched*, no
    ``bbox`` and ``seen`` 0."""
    p = _empty_partial(m_matched)
    if len(d):
        p["count"] = int(len(d))
        p["sum"] = float(d.sum())
        d2 = d * d
        p["sumsq"] = float(d2.sum())
        p["sum4"] = float((d2 * d2).sum())
        k = int(np.argmax(d))
        p["max"] = float(d[k])
        p["argmax"] = [float(v) for v in where[k]]
        p["hist"], p["zeros"] = _histogram(d)
    return p


def forward_chunk(xyz: np.ndarray, target: Target, *, select: np.ndarray | None = None,
                  backward_index: ExactIndex | None = None, n_backward: int | None = None,
                  keep: np.ndarray | None = None, normals: np.ndarray | None = None,
                  d2_k: int | None = None,
                  d2_rows: np.ndarray | None = None) -> tuple[dict, tuple[np.ndarray, np.ndarray] | None]:
    """Partial forward statistics of one chunk *xyz* (n, 3) of original points against *target*.

    *select*: rows to evaluate (a sample; all when None). *backward_index*,
    *n_backward*: in sampled mode, the sampled simplified points' index and
    count (else points at distance 0 are marked directly). *keep*: rows whose
    (xyz, distance) go to the error PLY. D2 (:func:`.planes.d2_squares`) with
    *d2_k* (None: no D2), file *normals*, *d2_rows* (positions in the D2 sample).

    Returns ``(partial, ply)``: ``count, sum, sumsq, sum4, d2sq, d2sq2,
    d2_count, max, argmax, zeros, hist, bbox, matched`` (packed bitmask of
    simplified points found exactly), ``seen``; and the *keep* rows'
    coordinates and errors, or None.
    """
    m = len(target) if n_backward is None else n_backward
    q = xyz if select is None else xyz[select]
    d, idx = target.query(q)
    p = stats_partial(d, q, m)
    p["seen"] = int(len(xyz))
    if d2_k is not None:
        pos = np.arange(len(q)) if d2_rows is None else d2_rows
        w = pos[d[pos] > 0]
        rows = w if select is None else select[w]
        sq = d2_squares(xyz, rows, target.points[idx[w]] - q[w], normals, d2_k)
        p["d2sq"], p["d2sq2"], p["d2_count"] = float(sq.sum()), float(np.dot(sq, sq)), int(len(pos))
    if len(xyz):
        p["bbox"] = np.stack([xyz.min(axis=0), xyz.max(axis=0)])
    mask = np.zeros(m, bool)
    if backward_index is None:
        mask[idx[d == 0]] = True
    else:
        hit, bidx = backward_index.lookup(xyz)
        mask[bidx[hit]] = True
    p["matched"] = np.packbits(mask)
    ply = None
    if keep is not None:
        if select is None:
            ply = (xyz[keep], d[keep].astype(np.float32))
        else:
            pos = np.searchsorted(select, keep)
            ply = (xyz[keep], d[pos].astype(np.float32))
    return p, ply


#: the partial results' fields that add up
_SUMMED = ("count", "sum", "sumsq", "sum4", "d2sq", "d2sq2", "d2_count", "zeros", "seen", "hist")


def combine(partials: list[dict]) -> dict:
    """Merge partial results (any grouping, any order) into one partial."""
    partials = list(partials)
    out = dict(partials[0])
    out["hist"] = out["hist"].copy()
    out["matched"] = out["matched"].copy()
    for p in partials[1:]:
        for key in _SUMMED:
            out[key] += p[key]
        np.bitwise_or(out["matched"], p["matched"], out=out["matched"])
        if p["count"] and (out["argmax"] is None or p["max"] > out["max"]):
            out["max"], out["argmax"] = p["max"], p["argmax"]
        if p["bbox"] is not None:
            if out["bbox"] is None:
                out["bbox"] = p["bbox"].copy()
            else:
                out["bbox"] = np.stack([np.minimum(out["bbox"][0], p["bbox"][0]),
                                        np.maximum(out["bbox"][1], p["bbox"][1])])
    return out


def d2_figures(partial: dict, population: int) -> dict:
    """``d2_mse`` of a combined partial, and when its D2 sample is smaller than *population*,
    ``d2_sample`` (its size) and ``d2_se`` (the MSE's standard error, finite-population corrected)."""
    dn = partial["d2_count"] or partial["count"]
    mse = partial["d2sq"] / dn if dn else 0.0
    out: dict[str, Any] = {"d2_mse": mse}
    if dn and population > dn:
        fpc = math.sqrt((population - dn) / (population - 1))
        var = max((partial["d2sq2"] - dn * mse * mse) / max(dn - 1, 1), 0.0)
        out.update({"d2_sample": int(dn), "d2_se": math.sqrt(var / dn) * fpc})
    return out


def aggregate(partial: dict, diagonal: float, population: int | None = None) -> dict:
    """Final figures from a :func:`combine` partial; ``*_pct`` in % of *diagonal*.
    Returns ``count, mean, rms, max, mean_pct, rms_pct, max_pct, zeros, argmax``, ``mse`` (D1) and
    :func:`d2_figures`; when *population* (the size the partial is a sample of) is given, also ``ci`` (95%
    intervals), ``population`` and ``max_is_lower_bound``."""
    n = partial["count"]
    if n == 0:
        raise EmptyInputError("no point to evaluate (0 distances)")
    mean = partial["sum"] / n
    msq = partial["sumsq"] / n
    rms = math.sqrt(max(msq, 0.0))
    mx = partial["max"]
    scale = 100.0 / diagonal if diagonal > 0 else float("nan")
    out: dict[str, Any] = {
        "count": int(n),
        "mean": mean,
        "rms": rms,
        "max": mx,
        "mean_pct": mean * scale,
        "rms_pct": rms * scale,
        "max_pct": mx * scale,
        "zeros": int(partial["zeros"]),
        "argmax": partial["argmax"],
        "mse": msq,
    }
    out.update(d2_figures(partial, population if population is not None else n))
    if population is not None and population > n:
        fpc = math.sqrt((population - n) / (population - 1)) if population > 1 else 0.0
        var = max((partial["sumsq"] - n * mean * mean) / max(n - 1, 1), 0.0)
        var2 = max((partial["sum4"] - n * msq * msq) / max(n - 1, 1), 0.0)
        h = _Z95 * math.sqrt(var / n) * fpc
        h2 = _Z95 * math.sqrt(var2 / n) * fpc
        ci_mean = [max(mean - h, 0.0), mean + h]
        ci_rms = [math.sqrt(max(msq - h2, 0.0)), math.sqrt(msq + h2)]
        out["population"] = int(population)
        out["ci"] = {
            "level": 0.95,
            "mean": ci_mean,
            "rms": ci_rms,
            "mean_pct": [v * scale for v in ci_mean],
            "rms_pct": [v * scale for v in ci_rms],
        }
        out["max_is_lower_bound"] = True
    return out
