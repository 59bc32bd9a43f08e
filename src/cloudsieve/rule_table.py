"""The rule table, a leaf: each pruning rule's metadata, the default rule, the warm-up targets' names.

Each rule is one :class:`Rule`, its selection under :mod:`cloudsieve.core.rules` loaded at first call.
The table (:data:`RULES`, :func:`get`, :func:`names`) is the only place rule names are written as strings;
it imports :mod:`cloudsieve.errors` only. Default rule: :func:`resolve_rule` (README, "Rules").

>>> from cloudsieve.rule_table import get, targets_of
>>> get("eliminate").clusters, get("threshold").target
(False, 'refused')
>>> targets_of("eliminate"), targets_of("threshold")
(('common', 'partition', 'eliminate'), ('common', 'partition', 'scores'))
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .errors import InvalidParameterError

__all__ = [
    "Rule", "RULES", "get", "names",
    "PAPER_THRESHOLD", "DEFAULT_RULE", "MEMORY_RULE", "THRESHOLD_RULE", "BOTH_RULE",
    "NEEDED", "OPTIONAL", "REFUSED", "GLOBAL_THRESHOLD", "CELL_COUNT", "ELIMINATION", "METHODS",
    "TARGETS", "ENTROPY_TARGETS", "targets_of",
    "Metavar", "resolve_rule",
]

#: S of the paper (Mahdaoui et al. 2017): the threshold of the rules that take one when none is given
PAPER_THRESHOLD = 1e-3

#: what :attr:`Rule.target` may be
NEEDED, OPTIONAL, REFUSED = "needed", "optional", "refused"
#: what :attr:`Rule.engine` may be: an engine cell with a target keeps score > T (one global threshold),
#: runs the rule to the count T leaves it, or the elimination (:mod:`cloudsieve.engine.eliminate`)
GLOBAL_THRESHOLD, CELL_COUNT, ELIMINATION = "global_threshold", "cell_count", "elimination"

#: the refinements into small clusters of the rules that use clusters: fuzzy C-means, K-means
#: (:mod:`cloudsieve.core.refine`)
METHODS = ("fcm", "km")

#: every warm-up target, in the order ``cloudsieve warmup`` runs them (:mod:`cloudsieve.core.warmup`)
TARGETS: tuple[str, ...] = ("common", "partition", "eliminate", "scores", "km", "fcm", "rules")
#: the targets of an entropy rule's worker tasks (a rule may name its own, :attr:`Rule.warm`); none starts
#: numba's threading layer (a fork server that has started GNU OpenMP's cannot fork)
ENTROPY_TARGETS: tuple[str, ...] = ("common", "partition", "scores")


@dataclass(frozen=True)
class Rule:
    """One pruning rule: ``name`` (the ``rule`` option's value); ``target`` ("needed", "optional": else
    the threshold S, "refused"); ``clusters`` (refines into KM/FCM clusters and scores ΔH; False: the
    entropy options are unused); ``options`` (user options read beside ratio/count); ``engine`` (what an
    engine cell runs with a target: "global_threshold", "cell_count", "elimination"); ``module`` (its
    in-memory selection under :mod:`cloudsieve.core.rules`); ``summary`` (help line); ``coverage_test``
    (drops a point only where its neighbours are at least as dense); ``warm`` (its warm-up targets).
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
    """Every rule's name, in the table's order."""
    return tuple(RULES)


def get(name: Any) -> Rule:
    """The rule called *name*; InvalidParameterError for an unknown one."""
    try:
        return RULES[name]
    except (KeyError, TypeError):
        raise InvalidParameterError(f"rule must be one of {', '.join(RULES)}, got {name!r}") from None


def targets_of(rule: str | None) -> tuple[str, ...]:
    """The warm-up targets of the worker tasks of a run of *rule*: the rule's own (the default rule's
    kernels), or for the entropy rules the scoring path (their refinement and rounds load from the cache)."""
    return (rule is not None and get(rule).warm) or ENTROPY_TARGETS


class Metavar(str):
    """A value an error advises without choosing it (``R``, ``N``, ``S``); its repr is itself.
    ``advice={"ratio": Metavar("R")}`` reads ``ratio=R`` (CLI: ``--ratio R``)."""

    __slots__ = ()

    def __repr__(self) -> str:
        return str(self)


def resolve_rule(command: str, o: dict, caller: str, metavars: Mapping[str, str]) -> None:
    """Resolve the default rule and threshold (None: not given) of *command*'s options *o*, once, in place.
    No rule: ``eliminate`` with a ratio or a count, ``threshold`` with a threshold alone, else
    InvalidParameterError (also for a threshold beside a ratio or count); the threshold defaults to
    :data:`PAPER_THRESHOLD`. *caller* names the call in the message; *metavars* the values left to the user."""
    has_target = o["ratio"] is not None or o["count"] is not None or o.get("density") is not None
    given = o["threshold"] is not None
    entropy = command == "simplify" or any(m in METHODS for m in o["methods"])
    if o["rule"] is None and not entropy:  # compare's baselines alone: no rule runs (compare wants a count)
        o["rule"] = [DEFAULT_RULE]
    if o["rule"] is None:
        if not has_target and not given:
            words = {name: Metavar(metavars[name]) for name in ("ratio", "count", "threshold")}
            exc = InvalidParameterError(
                f"{caller} needs ratio={words['ratio']!r} or count={words['count']!r} (the default rule, "
                f"{DEFAULT_RULE}, keeps exactly that many points), or threshold={words['threshold']!r} for the "
                "paper's threshold rule", advice=words)
            exc.caller = caller  # the command line words the API's name as its own (cloudsieve simplify)
            raise exc
        if has_target and given:
            name = next(n for n in ("ratio", "count", "density") if o.get(n) is not None)
            raise InvalidParameterError(
                f"threshold={o['threshold']!r} is the S of the paper's rules threshold and iterative, but with "
                f"{name}={o[name]!r} the default rule is {DEFAULT_RULE}, which takes no threshold: add "
                f"rule={BOTH_RULE!r} to use both, or leave the threshold out",
                advice={"threshold": o["threshold"], name: o[name], "rule": BOTH_RULE})
        rule = DEFAULT_RULE if has_target else THRESHOLD_RULE
        o["rule"] = rule if command == "simplify" else [rule]
    if not given:
        o["threshold"] = PAPER_THRESHOLD
