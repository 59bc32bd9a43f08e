"""cloudsieve: entropy-based simplification of point clouds too large for memory.

The public API:

- the whole job, out of core on dask: :func:`simplify`, :func:`evaluate`,
  :func:`compare`;
- the point store and IO: :class:`PointStore`, :func:`ingest`, :func:`export`,
  :func:`open_reader`, :func:`open_writer`, :func:`read_cloud`;
- the method in memory, on numpy arrays: :class:`KMeans`,
  :class:`FuzzyCMeans`, :func:`entropy_scores`, :func:`score_points`,
  :func:`simplify_points`, :func:`refine_labels`, :func:`prune`,
  :func:`unit_free_scores`, :func:`threshold_for_count`;
- pipelines: :func:`load_pipeline`, :func:`run_pipeline`;
- the exceptions (root :class:`CloudsieveError`).

open3d and pymeshlab are imported only when an evaluation needs them.
"""

from __future__ import annotations

import logging

from .core import FuzzyCMeans, KMeans, Scores, entropy_scores, score_points
from .store import PointStore, export, ingest
from .engine import Summary, simplify
from .errors import *  # noqa: F401,F403
from .errors import __all__ as _errors_all
from .evaluate import compare, evaluate
from .io import open_reader, open_writer, read_cloud
from .pipeline import load_pipeline, run_pipeline
from .core import prune, refine_labels, simplify_points, threshold_for_count, unit_free_scores

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "__version__",
    "simplify",
    "Summary",
    "evaluate",
    "compare",
    "PointStore",
    "ingest",
    "export",
    "open_reader",
    "open_writer",
    "read_cloud",
    "KMeans",
    "FuzzyCMeans",
    "entropy_scores",
    "score_points",
    "Scores",
    "simplify_points",
    "refine_labels",
    "prune",
    "unit_free_scores",
    "threshold_for_count",
    "load_pipeline",
    "run_pipeline",
    *_errors_all,
]
