"""The out-of-core run on dask: partition, cells, merge, export."""

from .cells import cell_seed
from .runner import DEFAULT_SCHEDULER
from .simplify import Summary, simplify
from .workstore import SIMPLIFY_ATTR

__all__ = ["simplify", "Summary", "DEFAULT_SCHEDULER", "SIMPLIFY_ATTR", "cell_seed"]
