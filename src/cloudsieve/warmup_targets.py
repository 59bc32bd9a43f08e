"""The names of the kernels' warm-up targets and each rule's: a leaf (the options and the run read it;
each rule's come from the registry, :mod:`cloudsieve.core.rules`, which imports no numba).

The targets themselves (what each compiles, on a tiny input) are in
:mod:`cloudsieve.core.warmup`; ``cloudsieve warmup --targets`` takes these names.
"""

from __future__ import annotations

__all__ = ["TARGETS", "ENTROPY_TARGETS", "targets_of"]

#: every warm-up target, in the order ``cloudsieve warmup`` runs them (:mod:`cloudsieve.core.warmup`)
TARGETS: tuple[str, ...] = ("common", "partition", "eliminate", "scores", "km", "fcm", "rules")

#: the targets of an entropy rule's worker tasks; a rule of the registry may name its own
#: (:attr:`cloudsieve.core.rules.Rule.warm`). The local fork server warms these up; none starts numba's
#: threading layer (a fork server that has started GNU OpenMP's cannot fork)
ENTROPY_TARGETS: tuple[str, ...] = ("common", "partition", "scores")


def targets_of(rule: str | None) -> tuple[str, ...]:
    """The warm-up targets of the worker tasks of a run of *rule*: the rule's own (the default rule's
    kernels), or for the entropy rules the scoring path (their refinement and rounds load from the cache).

    >>> from cloudsieve.core.rules import DEFAULT_RULE, THRESHOLD_RULE
    >>> targets_of(DEFAULT_RULE)
    ('common', 'partition', 'eliminate')
    >>> targets_of(THRESHOLD_RULE)
    ('common', 'partition', 'scores')
    """
    from .core import rules

    return (rule is not None and rules.get(rule).warm) or ENTROPY_TARGETS
