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

Each name is imported at its first use: ``import cloudsieve`` itself loads
no numba, dask, zarr, open3d or pymeshlab (open3d and pymeshlab only when an
evaluation needs them).
"""

from __future__ import annotations

import logging

from .errors import *  # noqa: F401,F403
from . import errors as _errors
from .lazy import keep_functions

#: where each public name lives; imported at its first use (module ``__getattr__``, PEP 562), so
#: ``import cloudsieve`` loads no numba, dask, zarr, open3d or pymeshlab
_LAZY = {
    "FuzzyCMeans": "core", "KMeans": "core", "Scores": "core", "entropy_scores": "core", "score_points": "core",
    "prune": "core", "refine_labels": "core", "simplify_points": "core", "threshold_for_count": "core",
    "unit_free_scores": "core",
    "PointStore": "store", "export": "store", "ingest": "store",
    "Summary": "engine", "simplify": "engine",
    "compare": "evaluate", "_evaluate": "evaluate",
    "open_reader": "io", "open_writer": "io", "read_cloud": "store",
    "load_pipeline": "pipeline", "run_pipeline": "pipeline",
}

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = ["__version__", *(name.lstrip("_") for name in _LAZY), *_errors.__all__]


def __getattr__(name: str):
    """A public name of :data:`_LAZY`, imported from its module at its first use."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name.lstrip("_"))
        if not name.startswith("_"):
            globals()[name] = value  # next time a plain attribute
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *(name.lstrip("_") for name in _LAZY)})


# cloudsieve.evaluate is always the function, never the subpackage of the same name
keep_functions(__name__, __getattr__, {"evaluate": "_evaluate"})
