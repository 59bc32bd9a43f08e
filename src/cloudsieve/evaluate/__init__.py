"""Evaluation: :func:`evaluate` (point-level errors and the paper's surface level of a simplified cloud against
its original, as a report) and :func:`compare` (entropy simplification and baselines at one count, one table).

Building blocks: :mod:`.points`, :mod:`.distances`, :mod:`.surface`, :mod:`.mesh`, :mod:`.baselines`,
:mod:`.report`.
"""

from __future__ import annotations

from .compare import compare
from .evaluation import check_compatible, evaluate

__all__ = ["evaluate", "compare", "check_compatible"]
