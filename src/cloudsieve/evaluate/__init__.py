"""Evaluation: what simplification cost, and how it compares with baselines.

- :func:`evaluate` — point-level errors (streamed, or sampled with confidence
  intervals) and the paper's surface level (ball-pivoting meshes, Metro
  distances, triangle compactness) of a simplified cloud against its
  original, as a report dict and, optionally, report files.
- :func:`compare` — run entropy simplification (KM, FCM) and baselines
  (random, voxel, Poisson disk, farthest point) to the same output count on a
  cloud that fits in memory, evaluate each, one table.

Building blocks: :mod:`.points`, :mod:`.distances`, :mod:`.surface`,
:mod:`.mesh`, :mod:`.baselines`, :mod:`.report`.
"""

from __future__ import annotations

from .compare import compare
from .evaluation import check_compatible, evaluate

__all__ = ["evaluate", "compare", "check_compatible"]
