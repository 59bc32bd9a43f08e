"""The global threshold of a ratio/count: one T on the unit-free scores of all cells.

A run asked for a ratio or a count keeps ``target`` of the N points: T is
chosen so that N - target points score <= T. Pass 1 of the cells stage
stored every cell's unit-free scores (m*dH) in ``simplify/score_cells``;
summed per-cell histograms of log10(score) (one small task per cell: the
chunk / combine / aggregate pattern) narrow T to a bin, whose few scores are
gathered and T picked exactly with :func:`cloudsieve.core.threshold_for_count`
(exact up to equal scores). Only histograms and the scores of one bin pass
through the scheduler, never an array of size N.
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
    """Histogram of log10 of one cell's stored scores over [lo, hi), plus under/over counts (a task).

    Returns
    -------
    ndarray of shape (bins + 2,), int64: [below lo, bins..., at or above hi]
    """
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
    """The stored scores of one cell with lo <= log10(score) < hi (few, by construction; a task).

    Returns
    -------
    ndarray of shape (k,), float64
    """
    s = _cell_scores(store_path, region, n)
    with np.errstate(divide="ignore"):
        ls = np.log10(s)
    return s[(ls >= lo) & (ls < hi)]


def global_threshold(store, part, regions: np.ndarray, runner, remove: int) -> float:
    """The global threshold T on the stored unit-free scores: *remove* points have score <= T.

    Summed histograms of log10(score) (one small task per cell) narrow the
    range that holds the remove-th smallest score until it holds few points;
    those scores are then gathered and T is picked exactly among them with
    :func:`cloudsieve.core.threshold_for_count`. Exact up to ties (equal
    scores go together). Every sum is over integers: the result does not
    depend on the task order.

    Parameters
    ----------
    store : PointStore
    part : Partition
    regions : ndarray of shape (P,), int64
        Start of each cell's region in ``simplify/score_cells``.
    runner : Runner
    remove : int
        Points to remove; -inf when <= 0, +inf when >= N.

    Returns
    -------
    float
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
