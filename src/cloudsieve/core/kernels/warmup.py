"""Moved: the warm-up is :mod:`cloudsieve.core.warmup`, the target names :mod:`cloudsieve.warmup_targets`.

Kept only until ``params.py``, ``engine/simplify.py`` and ``cli/warmup.py``
import from there (issue 29; they are changed on another branch): then delete
this module. :func:`warm_up` imports upward from here, which is why it goes.
"""

from __future__ import annotations

from ...warmup_targets import RULE_TARGETS, TARGETS, targets_of

__all__ = ["TARGETS", "RULE_TARGETS", "warm_up", "targets_of"]


def warm_up(*args, **kwargs) -> float:
    """:func:`cloudsieve.core.warmup.warm_up`."""
    from ..warmup import warm_up as run

    return run(*args, **kwargs)
