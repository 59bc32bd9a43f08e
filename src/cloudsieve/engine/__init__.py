"""The out-of-core run on dask: partition, cells, merge, export."""

from .simplify import DEFAULT_SCHEDULER, SIMPLIFY_ATTR, Summary, cell_seed, simplify

__all__ = ["simplify", "Summary", "DEFAULT_SCHEDULER", "SIMPLIFY_ATTR", "cell_seed"]
