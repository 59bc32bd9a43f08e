"""Every user option of cloudsieve checked once: :func:`validate`, :func:`validate_params`.

The options are data in :mod:`cloudsieve.params_spec` (re-exported). The
command line, pipelines, :func:`cloudsieve.simplify`, :func:`cloudsieve.evaluate`,
:func:`cloudsieve.compare` and the in-memory API (:func:`validate_params`)
check them here, once, before any work, so all refuse the same values with
the same message. A leaf. A count above the cloud's size keeps every point.

>>> from cloudsieve.params import validate
>>> validate("simplify", {"method": "km", "ratio": 0.5})["cluster_size"]
400
"""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable, Mapping
from typing import Any

from . import rule_table as rules
from .errors import InvalidParameterError
from .params_spec import *  # noqa: F401,F403 - the options, re-exported
from .params_spec import COMMANDS, MEMORY_COMMANDS, OPTION_CLASSES, OPTIONS
from .params_values import check, named
from .params_spec import __all__ as _spec_all
from .rule_table import DEFAULT_RULE, Metavar, resolve_rule

#: the side of the areas of the density option when density_cell is not given (CRS units)
DENSITY_CELL = 10.0
#: the rule of the elimination engine, named in the messages of its own options
_ELIMINATION = next(r.name for r in rules.RULES.values() if r.engine == rules.ELIMINATION)

__all__ = [
    *_spec_all,
    "DENSITY_CELL",
    "density_floor",
    "DEFAULT_RULE",
    "Metavar",
    "check",
    "validate",
    "given",
    "options",
    "validate_params",
    "run_record",
]

# ---------------------------------------------------------------- a command's options


def _target(o: dict) -> None:
    if o["ratio"] is not None and o["count"] is not None:
        raise InvalidParameterError(f"give ratio or count, not both (got ratio={o['ratio']}, count={o['count']})")


def _cluster_size(o: dict) -> None:
    if o["cluster_size"] < o["k_min"] + 2:
        raise InvalidParameterError(
            f"cluster_size={o['cluster_size']!r} is too small: a cluster needs at least "
            f"k_min+2={o['k_min'] + 2} points", advice={"cluster_size": o["cluster_size"]})


def _rule_target(o: dict) -> None:
    """The rule's target: needed, or refused (the registry says which)."""
    rule = rules.get(o["rule"])
    has_target = o["ratio"] is not None or o["count"] is not None or o.get("density") is not None
    if rule.needs_target and not has_target:
        raise InvalidParameterError(f"rule {rule.name!r} needs a ratio or a count")
    if not rule.takes_target and has_target:
        others = [r.name for r in rules.RULES.values() if r.clusters and r.takes_target]
        raise InvalidParameterError(
            f"rule {rule.name!r} takes a threshold only, not ratio={o['ratio']}/count={o['count']}: "
            f"use rule {' or '.join(map(repr, others))}")


def _class_policy(o: dict) -> None:
    """keep_class and class_ratio: options of the elimination rule only; a class in one of them only."""
    given = [name for name in ("keep_class", "class_ratio") if o[name] is not None]
    if not given:
        return
    rule = rules.get(o["rule"])
    if rule.engine != rules.ELIMINATION:
        raise named(InvalidParameterError(f"{given[0]} is an option of rule {_ELIMINATION!r} only, not of rule "
                                          f"{rule.name!r}"), *given)
    both = sorted(set(o["keep_class"] or ()) & {code for code, ratio in o["class_ratio"] or () if ratio < 1})
    if both:
        raise named(InvalidParameterError(f"class {both[0]} is in keep_class and has a ratio below 1 in "
                                          f"class_ratio: give it in one of them"), "keep_class", "class_ratio")


def _density(o: dict) -> None:
    """density (with density_cell): of the elimination rule only, instead of ratio/count, the class policies, the
    gap bound and the ranks; an area keeps at least one point."""
    d, side = o["density"], DENSITY_CELL if o["density_cell"] is None else o["density_cell"]
    if d is None and o["density_cell"] is not None:
        raise named(InvalidParameterError("density_cell is the side of the areas of density: give density too (got "
                                          f"density_cell={side:g})"), "density_cell", "density")
    rule = rules.get(o["rule"])
    if d is not None and rule.engine != rules.ELIMINATION:
        raise named(InvalidParameterError(f"density is an option of rule {_ELIMINATION!r} only, not of rule "
                                          f"{rule.name!r}"), "density")
    for name in ("ratio", "count", "keep_class", "class_ratio", "max_gap", "rank"):
        if d is not None and o[name] not in (None, False):
            raise named(InvalidParameterError(f"give density or {name}, not both (got density={d:g}, "
                                              f"{name}={o[name]})"), "density", name)
    dims = 3 if o["density_3d"] else 2
    if d is None and o["density_3d"]:
        raise named(InvalidParameterError("density_3d counts density per cubic unit: give density too"),
                    "density_3d", "density")
    if d is not None and density_floor(d, side, dims) < 1:
        raise named(InvalidParameterError(f"density * density_cell^{dims} must be at least 1 point per "
                                          f"{'cube' if dims == 3 else 'area'}, got {d:g} * {side:g}^{dims} = "
                                          f"{d * side ** dims:g}"), "density", "density_cell")


def density_floor(density: float, side: float, dims: int = 2) -> int:
    """Points an area (*dims* 3: a cube) of side *side* keeps at most at *density*: floor(D R^dims), D R^dims
    rounded to 9 decimals first (0.29 * 10^2 is 29, not 28.999...)."""
    return int(math.floor(round(float(density) * float(side) ** dims, 9)))


def _simplify(o: dict) -> None:
    _density(o)
    _rule_target(o)
    listed = next((name for name in ("ratio", "count") if isinstance(o[name], tuple)), None)
    if listed and rules.get(o["rule"]).engine != rules.ELIMINATION:
        raise named(InvalidParameterError(f"a list of {listed}s (nested outputs) needs the rule "
                                          f"{rules.DEFAULT_RULE!r}, not {o['rule']!r}"), listed)
    policy = next((name for name in ("keep_class", "class_ratio", "max_gap") if o[name] is not None), None)
    if listed and policy:  # a later output would count (or bound) against the output before, not the input
        raise named(InvalidParameterError(f"a list of {listed}s (nested outputs) does not take {policy}: run one "
                                          f"{listed} at a time"), listed, policy)
    if o["rank"] and rules.get(o["rule"]).engine != rules.ELIMINATION:
        raise named(InvalidParameterError(f"rank needs the rule {rules.DEFAULT_RULE!r}, not {o['rule']!r}"), "rank")
    if o["max_gap"] is not None and rules.get(o["rule"]).engine != rules.ELIMINATION:
        raise named(InvalidParameterError(f"max_gap needs the rule eliminate (the default), not rule "
                                          f"{o['rule']!r}"), "max_gap")
    _cluster_size(o)
    _class_policy(o)
    if o["cell_size"] < o["cluster_size"]:
        raise InvalidParameterError(f"cell_size ({o['cell_size']}) must be >= cluster_size ({o['cluster_size']})")
    if o["memory_limit"] is not None and o["scheduler"] not in (None, "processes"):
        raise InvalidParameterError(
            f"memory_limit ({o['memory_limit']}) needs worker processes: use the default scheduler or "
            f"'processes', not {o['scheduler']!r}")


def _evaluate(o: dict) -> None:
    if o["reference_mesh"] is not None and not o["surface"]:
        raise InvalidParameterError(f"reference_mesh ({o['reference_mesh']}) needs the surface level, which "
                                    "surface=False (--no-surface) turns off")


def _simplify_points(o: dict) -> None:
    _rule_target(o)
    _cluster_size(o)


def _eliminate(o: dict) -> None:
    _rule_target({**o, "rule": _ELIMINATION})  # the eliminate rule's target: needed


_CROSS = {"simplify": _simplify, "compare": _cluster_size, "simplify_points": _simplify_points, "prune": _rule_target,
          "refine": _cluster_size, "evaluate": _evaluate, "eliminate": _eliminate}


def validate(command: str, values: Mapping[str, Any], *, caller: str | None = None) -> dict[str, Any]:
    """Validate the options of *command* (a key of :data:`COMMANDS`), alone and together; returns all, normalised.
    *values* holds some options (the others take their defaults); *caller* names the call in errors (default
    ``cloudsieve.<command>``). For ``simplify`` and ``compare`` the rule is resolved here
    (:func:`cloudsieve.rule_table.resolve_rule`), so validating the result gives it back. InvalidParameterError for
    an unknown option, a value out of range, or contradicting options."""
    spec = COMMANDS[command]
    unknown = sorted(set(values) - set(spec))
    if unknown:
        raise InvalidParameterError(f"{command}: unknown option(s) {unknown}; accepted: {sorted(spec)}")
    out = {name: check(opt, values.get(name, opt.default)) for name, opt in spec.items()}
    many = [name for name, opt in spec.items() if opt.many and isinstance(out[name], tuple)]
    if many and command != "simplify":
        raise named(InvalidParameterError(f"{many[0]} takes one value here, got {values[many[0]]!r} (a list writes "
                                          f"nested outputs, in cloudsieve.simplify)"), many[0])
    if command in _CROSS:
        if "ratio" in out:
            _target(out)
        if "rule" in out and command not in MEMORY_COMMANDS:  # simplify, compare: the default rule
            resolve_rule(command, out, caller or f"cloudsieve.{command}",
                         {name: OPTIONS[name].metavar for name in ("ratio", "count", "threshold")})
        _CROSS[command](out)
    return out


def options(command: str, values: Mapping[str, Any], *, caller: str | None = None) -> Any:
    """:func:`validate`'s result as *command*'s frozen options object (:data:`OPTION_CLASSES`), to pass whole.

    >>> options("evaluate", {"sample": 1000}).sample
    1000
    """
    return OPTION_CLASSES[command](**validate(command, values, caller=caller))


def given(command: str, values: Mapping[str, Any]) -> dict[str, Any]:
    """The options of *command* among *values* (a public function's ``locals()`` on entry: its arguments), for
    :func:`validate` or :func:`options`."""
    return {name: value for name, value in values.items() if name in COMMANDS[command]}


def validate_params(command: str) -> Callable[[Callable], Callable]:
    """Decorate a public function: its options are validated once by :func:`validate` before it runs
    (values passed as given, not normalised)."""
    spec = COMMANDS[command]

    def decorate(func: Callable) -> Callable:
        signature = inspect.signature(func)
        names = [n for n in signature.parameters if n in spec]

        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            validate(command, {n: bound.arguments[n] for n in names})
            return func(*args, **kwargs)

        wrapper.unchecked = func  # for callers whose options were validated already
        return wrapper

    return decorate


def run_record(options: Mapping[str, Any]) -> dict[str, Any]:
    """The options that define a simplification, as its work store records them (resume compares them).
    halo_context is recorded as ``"context"``, keep_duplicates only when True and max_gap only when given, so
    version-1 work stores still resume."""
    keys = ("method", "rule", "threshold", "ratio", "count", "cluster_size", "cell_size", "seed")
    record = {k: options[k] for k in keys}
    record.update(context=options["halo_context"], k0=options["k0"], k_min=options["k_min"])
    if options.get("keep_duplicates"):
        record["keep_duplicates"] = True
    if options.get("max_gap") is not None:
        record["max_gap"] = options["max_gap"]
    # only when given: a run without them records what it did
    for name in ("keep_class", "class_ratio", "density", "density_cell", "density_3d"):
        if options.get(name) not in (None, False):
            record[name] = options[name]
    return record
