"""Rule eliminate (cloudsieve's; the default): weighted sample elimination to an exact count.

Exactly ``target`` points kept, as a run of the engine keeps them
(:func:`cloudsieve.engine.cell_scheme.eliminate_points`: the partition into
cells, each cell's elimination with its halo; labels and scores are not
used). Exact copies go first and are kept only when the distinct points do
not make the count; with ``keep_duplicates`` every copy of a kept point
stays. Its entry in the registry is :data:`cloudsieve.core.rules.RULES`.
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
