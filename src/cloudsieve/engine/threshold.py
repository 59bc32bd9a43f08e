"""The global threshold of a ratio/count: one T on the unit-free scores of all cells.

T is chosen so that N - target points score <= T. Per-cell histograms of
log10(score), summed, narrow T to a bin whose few scores are gathered;
:func:`cloudsieve.core.threshold_for_count` picks T among them (exact up to
equal scores). Only histograms and one bin's scores pass through the
scheduler, and every sum is over integers (independent of task order).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["global_threshold", "score_hist_task", "scores_between_task"]

#: histogram of log10(score) used to choose a global threshold
_HIST_LO = -16.0
_HIST_HI = 4.0
_HIST_BINS = 4000
#: gather the scores of the threshold's bin once it holds at most this many
_GATHER_MAX = 200_000


def _cell_scores(store_path: str, region: int, n: int) -> np.ndarray:
    from ..store import PointStore

    st = PointStore.open(store_path, "r")
    return np.asarray(st.group["simplify/score_cells"][region : region + n])


def score_hist_task(store_path: str, region: int, n: int, lo: float, hi: float, bins: int) -> np.ndarray:
    """Task: histogram (bins + 2,) int64 of log10 of one cell's scores over [lo, hi), with below/above counts at the ends."""
    s = _cell_scores(store_path, region, n)
    with np.errstate(divide="ignore"):
        ls = np.log10(s)
    out = np.zeros(bins + 2, dtype=np.int64)
    out[0] = int((ls < lo).sum())
    out[-1] = int((ls >= hi).sum())
    inside = ls[(ls >= lo) & (ls < hi)]
    idx = np.minimum(((inside - lo) / (hi - lo) * bins).astype(np.int64), bins - 1)
    out[1:-1] = np.bincount(idx, minlength=bins)
    return out


def scores_between_task(store_path: str, region: int, n: int, lo: float, hi: float) -> np.ndarray:
    """Task: one cell's scores (k,) with lo <= log10(score) < hi (few, by construction)."""
    s = _cell_scores(store_path, region, n)
    with np.errstate(divide="ignore"):
        ls = np.log10(s)
    return s[(ls >= lo) & (ls < hi)]


def global_threshold(store, part, regions: np.ndarray, runner, remove: int) -> float:
    """The global threshold T on the stored unit-free scores: *remove* points have score <= T.

    *regions*: each cell's start in ``simplify/score_cells``. Returns -inf
    when *remove* <= 0, +inf when >= N.
    """
    from ..core import threshold_for_count

    counts = part.cell_counts
    cells = [j for j in range(part.n_cells) if counts[j] > 0]
    total = int(counts.sum())
    if remove <= 0:
        return -math.inf
    if remove >= total:
        return math.inf
    lo = _HIST_LO
    hi = _HIST_HI
    bins = _HIST_BINS
    for _ in range(6):
        hists = runner(
            score_hist_task, [(store.path, int(regions[j]), int(counts[j]), lo, hi, bins) for j in cells], "cells: threshold"
        )
        h = np.sum(np.stack(hists), axis=0)
        cum = np.cumsum(h)  # cum[0]: all scores below lo
        b = int(np.searchsorted(cum, remove, side="left"))
        if b == 0:  # among the scores below the range (zeros: duplicates): all go together
            return 10.0**lo if lo > _HIST_LO else 0.0
        if b >= bins + 1:  # among the scores above the range (+inf: always kept)
            return math.inf
        width = (hi - lo) / bins
        edge_lo, edge_hi = lo + (b - 1) * width, lo + b * width
        below = int(cum[b - 1])
        if h[b] <= _GATHER_MAX or width < 1e-9:
            parts = runner(
                scores_between_task,
                [(store.path, int(regions[j]), int(counts[j]), edge_lo, edge_hi) for j in cells],
                "cells: threshold",
            )
            inside = np.concatenate(parts) if parts else np.empty(0)
            return float(threshold_for_count(inside, remove - below))
        lo, hi = edge_lo, edge_hi
    return 10.0**hi
