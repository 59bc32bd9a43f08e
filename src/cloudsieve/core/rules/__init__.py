"""The pruning rules as a registry (DESIGN.md, "Rules as a registry"): one module per rule.

Each rule module (:mod:`.threshold`, :mod:`.iterative`, :mod:`.target`,
:mod:`.coverage`, :mod:`.eliminate`) declares one :class:`Rule`: its name,
whether it needs a target (a ratio or a count), takes one or refuses one,
whether it uses clusters (KM/FCM), the user options it reads, the work of an
engine cell with a target, its warm-up targets, and its in-memory selection
(:meth:`Rule.prune`, imported at its first call). Callers ask the registry
(:data:`RULES`, :func:`get`, :func:`names`); this package is the only place
rule names are written as strings.

This module imports no numba and no scipy: :mod:`cloudsieve.params` reads it
to build the ``rule`` option. The rules' entry points on arrays
(:func:`prune`, :func:`unit_free_scores`, :func:`threshold_for_count`,
:func:`check_rule_args`, :func:`prune_unchecked`) are in :mod:`.dispatch` and
imported from here at their first use.

>>> from cloudsieve.core import rules
>>> rules.get("eliminate").clusters, rules.get("threshold").target
(False, 'refused')
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module
from typing import Any

from ...errors import InvalidParameterError

__all__ = [
    "Rule",
    "RULES",
    "PAPER_THRESHOLD",
    "DEFAULT_RULE",
    "MEMORY_RULE",
    "THRESHOLD_RULE",
    "BOTH_RULE",
    "get",
    "names",
    "prune",
    "unit_free_scores",
    "threshold_for_count",
    "check_rule_args",
    "prune_unchecked",
]

#: S of the paper (Mahdaoui et al. 2017): the threshold of the rules that take one when none is given
PAPER_THRESHOLD = 1e-3

#: what :attr:`Rule.target` may be
NEEDED, OPTIONAL, REFUSED = "needed", "optional", "refused"
#: what :attr:`Rule.engine` may be: an engine cell with a target keeps score > T (one global threshold),
#: runs the rule to the count T leaves it, or the elimination (:mod:`cloudsieve.engine.eliminate`)
GLOBAL_THRESHOLD, CELL_COUNT, ELIMINATION = "global_threshold", "cell_count", "elimination"


@dataclass(frozen=True)
class Rule:
    """One pruning rule.

    Attributes
    ----------
    name : str
        The value of the ``rule`` option.
    target : {"needed", "optional", "refused"}
        Whether the rule needs a ratio or a count, may take one (else it uses
        the threshold S), or takes the threshold S only.
    clusters : bool
        Whether it refines into small clusters (KM/FCM) and scores ΔH; False:
        ``method``, ``cluster_size`` and the entropy options are unused.
    options : tuple of str
        The user options (:mod:`cloudsieve.params`) it reads beside ratio/count.
    engine : {"global_threshold", "cell_count", "elimination"}
        What the engine runs per cell with a ratio or a count (without one,
        each cell runs :meth:`prune` through the in-memory method).
    coverage_test : bool
        Its rounds drop a point only where its neighbours are at least as dense.
    warm : tuple of str
        The warm-up targets its runs compile (:mod:`cloudsieve.warmup_targets`).
    module : str
        The module of its in-memory selection, imported at the first call.
    summary : str
        One line for the help.
    """

    name: str
    target: str
    clusters: bool
    options: tuple[str, ...]
    engine: str
    module: str
    summary: str
    coverage_test: bool = False
    warm: tuple[str, ...] = ()

    @property
    def needs_target(self) -> bool:
        """A ratio or a count is required."""
        return self.target == NEEDED

    @property
    def takes_target(self) -> bool:
        """A ratio or a count is accepted."""
        return self.target != REFUSED

    @property
    def takes_threshold(self) -> bool:
        """The threshold S is read (without a target)."""
        return "threshold" in self.options

    def prune(self, pts, lab, **kw: Any):
        """The keep mask (n,) bool of validated points and labels (:func:`.dispatch.prune_unchecked`'s arguments)."""
        return import_module(self.module, __name__).prune(self, pts, lab, **kw)


_ENTROPY = ("method", "cluster_size", "k0", "k_min", "halo_context", "keep_duplicates")

RULES: dict[str, Rule] = {r.name: r for r in (
    Rule("iterative", OPTIONAL, True, ("threshold", *_ENTROPY), CELL_COUNT, ".iterative",
         "the paper's test in rounds, no two dropped points k-NN neighbours; S or a ratio/count"),
    Rule("threshold", REFUSED, True, ("threshold", *_ENTROPY), GLOBAL_THRESHOLD, ".threshold",
         "the paper's one pass: drop every point with dH <= S"),
    Rule("target", NEEDED, True, _ENTROPY, GLOBAL_THRESHOLD, ".target",
         "a ratio/count: one global threshold on the unit-free m*dH"),
    Rule("coverage", OPTIONAL, True, ("threshold", *_ENTROPY), CELL_COUNT, ".coverage",
         "iterative where a point goes only if its neighbours are at least as dense", coverage_test=True),
    Rule("eliminate", NEEDED, False, ("keep_duplicates",), ELIMINATION, ".eliminate",
         "weighted sample elimination, exactly the ratio/count, no clusters",
         warm=("common", "partition", "eliminate")),
)}

#: the rule of :func:`cloudsieve.simplify`, the CLI and the pipelines when none is given and a ratio or count is
DEFAULT_RULE = "eliminate"
#: the rule a threshold alone selects (the paper's)
THRESHOLD_RULE = "threshold"
#: the rule advised to use a threshold and a ratio/count together
BOTH_RULE = "iterative"
#: the default of the in-memory method :func:`cloudsieve.core.simplify_points` (needs no ratio or count)
MEMORY_RULE = "iterative"


def names() -> tuple[str, ...]:
    """Every rule's name, in the registry's order."""
    return tuple(RULES)


def get(name: Any) -> Rule:
    """The rule called *name*.

    Raises
    ------
    InvalidParameterError
        ``rule must be one of iterative, threshold, target, coverage, eliminate, got 'x'``.
    """
    try:
        return RULES[name]
    except (KeyError, TypeError):
        raise InvalidParameterError(f"rule must be one of {', '.join(RULES)}, got {name!r}") from None


_DISPATCH = {"prune", "unit_free_scores", "threshold_for_count", "check_rule_args", "prune_unchecked"}


def __getattr__(name: str):
    if name in _DISPATCH:
        value = getattr(import_module(".dispatch", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
