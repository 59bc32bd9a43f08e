"""The pruning rules (DESIGN.md, "Rules as a registry"): one module per rule.

Each rule module (:mod:`.threshold`, :mod:`.iterative`, :mod:`.target`,
:mod:`.coverage`, :mod:`.eliminate`) holds its selection,
``prune(rule, pts, lab, **kw)`` on validated input. Their metadata is the rule
table, :mod:`cloudsieve.rule_table`, re-exported here; callers ask it
(:data:`RULES`, :func:`get`, :func:`names`), never compare rule names. Entry points
on arrays are in :mod:`.dispatch`, imported at first use.

>>> from cloudsieve.core import rules
>>> rules.get("eliminate").clusters, rules.get("threshold").target
(False, 'refused')
"""

from __future__ import annotations

from importlib import import_module

from ...rule_table import (BOTH_RULE, CELL_COUNT, DEFAULT_RULE, ELIMINATION, GLOBAL_THRESHOLD, MEMORY_RULE,
                           PAPER_THRESHOLD, RULES, THRESHOLD_RULE, Rule, get, names)

__all__ = [
    "Rule",
    "RULES",
    "PAPER_THRESHOLD",
    "DEFAULT_RULE",
    "MEMORY_RULE",
    "THRESHOLD_RULE",
    "BOTH_RULE",
    "GLOBAL_THRESHOLD",
    "CELL_COUNT",
    "ELIMINATION",
    "get",
    "names",
    "prune",
    "unit_free_scores",
    "threshold_for_count",
    "check_rule_args",
    "prune_unchecked",
]

_DISPATCH = {"prune", "unit_free_scores", "threshold_for_count", "check_rule_args", "prune_unchecked"}


def __getattr__(name: str):
    if name in _DISPATCH:
        value = getattr(import_module(".dispatch", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
