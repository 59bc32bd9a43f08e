"""The default rule, resolved once, by :func:`cloudsieve.params.validate`.

Without a rule, a ratio or a count selects :data:`DEFAULT_RULE`
(``eliminate``: weighted sample elimination, an exact count) and a threshold
alone the paper's one-pass ``threshold`` rule; with none of them, or a
threshold beside a ratio or count, the options are refused before any work.
Why eliminate: README, "Rules" and the quality tables it points at.
"""

from __future__ import annotations

from collections.abc import Mapping

from .core.rules import BOTH_RULE, DEFAULT_RULE, PAPER_THRESHOLD, THRESHOLD_RULE
from .errors import InvalidParameterError
from .params_spec import METHODS

__all__ = ["DEFAULT_RULE", "Metavar", "resolve_rule"]



class Metavar(str):
    """A value an error advises without choosing it (``R``, ``N``, ``S``); its repr is itself.

    In ``InvalidParameterError(..., advice={"ratio": Metavar("R")})`` the
    message words it as the API does, ``ratio=R``; the command line rewrites
    that as ``--ratio R``.
    """

    __slots__ = ()

    def __repr__(self) -> str:
        return str(self)


def resolve_rule(command: str, o: dict, caller: str, metavars: Mapping[str, str]) -> None:
    """Resolve the default rule (None: not given) and threshold (None: not given), once, in place.

    No rule: ``eliminate`` with a ratio or a count; ``threshold`` with a
    threshold alone; neither is an error. The threshold becomes
    :data:`PAPER_THRESHOLD` when not given (what the work store records).

    Parameters
    ----------
    command : {"simplify", "compare"}
        compare's rule is a list of rules.
    o : dict
        The command's options, each already checked alone
        (:func:`cloudsieve.params.validate`); ``rule`` and ``threshold`` are
        set here.
    caller : str
        The call's name in the message: ``cloudsieve.simplify`` (the API),
        ``cloudsieve simplify`` (the CLI), ``filters.entropy`` (a pipeline stage).
    metavars : mapping of str to str
        The values an error leaves to the user, by option (``{"ratio": "R", ...}``).

    Raises
    ------
    InvalidParameterError
        No rule and neither a ratio, a count nor a threshold (for compare:
        when an entropy method runs), or no rule and a threshold beside a
        ratio or count. The advice holds :class:`Metavar` values or the given ones.
    """
    has_target = o["ratio"] is not None or o["count"] is not None
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
            name = "ratio" if o["ratio"] is not None else "count"
            raise InvalidParameterError(
                f"threshold={o['threshold']!r} is the S of the paper's rules threshold and iterative, but with "
                f"{name}={o[name]!r} the default rule is {DEFAULT_RULE}, which takes no threshold: add "
                f"rule={BOTH_RULE!r} to use both, or leave the threshold out",
                advice={"threshold": o["threshold"], name: o[name], "rule": BOTH_RULE})
        rule = DEFAULT_RULE if has_target else THRESHOLD_RULE
        o["rule"] = rule if command == "simplify" else [rule]
    if not given:
        o["threshold"] = PAPER_THRESHOLD
