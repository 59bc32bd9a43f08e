"""The names of the kernels' warm-up targets and each rule's: a leaf (the options and the run read it).

The targets themselves (what each compiles, on a tiny input) are in
:mod:`cloudsieve.core.warmup`; ``cloudsieve warmup --targets`` takes these names.
"""

from __future__ import annotations

__all__ = ["TARGETS", "RULE_TARGETS", "targets_of"]

#: every warm-up target, in the order ``cloudsieve warmup`` runs them (:mod:`cloudsieve.core.warmup`)
TARGETS: tuple[str, ...] = ("common", "partition", "eliminate", "scores", "km", "fcm", "rules")

#: the targets of each rule's worker tasks (the local fork server warms these up); none starts numba's
#: threading layer (a fork server that has started GNU OpenMP's cannot fork)
RULE_TARGETS: dict[str, tuple[str, ...]] = {"eliminate": ("common", "partition", "eliminate")}


def targets_of(rule: str | None) -> tuple[str, ...]:
    """The warm-up targets of the worker tasks of a run of *rule*: the default rule's kernels, or for the
    entropy rules the scoring path (their refinement and rounds load from the cache).

    >>> targets_of("eliminate")
    ('common', 'partition', 'eliminate')
    >>> targets_of("threshold")
    ('common', 'partition', 'scores')
    """
    return RULE_TARGETS.get(rule or "", ("common", "partition", "scores"))
