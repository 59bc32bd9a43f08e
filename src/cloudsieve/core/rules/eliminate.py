"""Rule eliminate (cloudsieve's; the default): weighted sample elimination to an exact count.

Keeps exactly ``target`` points as the engine does
(:func:`cloudsieve.engine.cell_scheme.eliminate_points`; no labels or scores).
Copies go first; ``keep_duplicates`` keeps every copy of a kept point.
"""

from __future__ import annotations

import numpy as np

__all__ = ["prune", "select"]


def select(pts, *, target, seed, cluster_size, k0, k_min, progress, keep_duplicates) -> np.ndarray:
    """The keep mask (n,) bool of the engine's elimination of *pts* to *target* points with these options."""
    from ...engine.cell_scheme import eliminate_points
    from ...progress import callback

    keep = eliminate_points(pts, target, seed=seed, cluster_size=cluster_size, k0=k0, k_min=k_min,
                            keep_duplicates=keep_duplicates)
    callback(progress)(len(pts) - int(keep.sum()))
    return keep


def prune(rule, pts, lab, options, *, target, progress, **_unused) -> np.ndarray:
    """:func:`select` with the default seed and cluster size (``simplify_points``'), *options* prune's."""
    from ...params import COMMANDS

    spec = COMMANDS["simplify_points"]
    return select(pts, target=target, seed=spec["seed"].default, cluster_size=spec["cluster_size"].default,
                  k0=options.k0, k_min=options.k_min, progress=progress, keep_duplicates=options.keep_duplicates)
