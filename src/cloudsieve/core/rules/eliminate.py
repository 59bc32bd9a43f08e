"""Rule eliminate (cloudsieve's; the default): weighted sample elimination to an exact count.

Exactly ``target`` points kept (:func:`cloudsieve.core.eliminate.eliminate`;
its entropy and geometric terms are off here, so labels and scores are not
used). Exact copies go first (priority +inf) and never weigh; with
``keep_duplicates`` every copy of a kept point stays. Out of core:
:mod:`cloudsieve.engine.eliminate`. Its entry in the registry is
:data:`cloudsieve.core.rules.RULES`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["prune"]


def prune(rule, pts, lab, options, *, target, progress, **_unused) -> np.ndarray:
    """The keep mask (n,) bool of the elimination to *target* points (copies kept at most once)."""
    from ...progress import callback
    from ..duplicates import copy_rows, first_rows
    from ..eliminate import eliminate

    n = len(pts)
    keep = np.zeros(n, dtype=bool)
    target = min(target, n - int(copy_rows(pts).sum()))  # copies kept at most once
    keep[eliminate.unchecked(pts, count=target, threads=options.threads)] = True  # the options were validated by the caller
    if options.keep_duplicates:  # every copy of a kept point (the first copy is the one the elimination may keep)
        keep = keep[first_rows(pts)]
    callback(progress)(n - int(keep.sum()))
    return keep
