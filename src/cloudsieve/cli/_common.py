"""The subcommands' options, generated from :mod:`cloudsieve.params`.

argparse only parses text; :func:`cloudsieve.params.validate` checks
values, so the command line, the pipelines and the API refuse the same
values with the same message.
"""

from __future__ import annotations

import argparse
import contextlib
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

from .. import params
from ..errors import CloudsieveError

__all__ = ["add_options", "option_values", "parse_int", "parse_float", "parse_numbers", "positive_int", "flag_wording", "cli_message"]


def parse_int(text: str) -> int | float:
    """argparse type of an integer option: ``1000000``, ``1_000_000`` or ``1e6`` (2.5 is left for the range check)."""
    clean = text.replace("_", "")
    try:
        return int(clean)
    except ValueError:
        pass
    try:
        value = float(clean)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    return int(value) if value.is_integer() else value


def parse_float(text: str) -> float:
    """argparse type of a number option."""
    try:
        return float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def parse_numbers(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """argparse type of a number option that takes a list: ``0.5`` or ``0.5,0.2,0.1`` (a list of two or more)."""

    def numbers(text: str) -> Any:
        try:
            values = [parse(item.strip()) for item in text.split(",")]
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"not a number or a comma-separated list of numbers: {text!r}") from None
        return values[0] if len(values) == 1 else values

    return numbers


def positive_int(text: str) -> int:
    """argparse type: an integer > 0 (for CLI-only options such as ``demo --points``)."""
    value = parse_int(text)
    if not isinstance(value, int) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be an integer > 0, got {text!r}")
    return value


def _size(text: str) -> int | str:
    return int(text) if text.isdigit() else text


_TYPES = {params.INT: parse_int, params.FLOAT: parse_float, params.SIZE: _size}


def add_options(parser: argparse.ArgumentParser, command: str, names: Iterable[str] | None = None, *,
                defaults: Mapping[str, Any] | None = None, helps: Mapping[str, str] | None = None) -> None:
    """Add the options of *command* (all, or *names*) to *parser*, from the spec.
    Flags are the names with dashes, ``--no-NAME`` for a bool defaulting to True; aliases are other flags. *defaults*
    and *helps* override the spec's (``demo`` has some of simplify's options only)."""
    spec = params.COMMANDS[command]
    defaults, helps = defaults or {}, helps or {}
    for name in names if names is not None else spec:
        opt = spec[name]
        default = defaults.get(name, opt.default)
        flags = (opt.flag, *opt.aliases)
        text = helps.get(name, opt.help)
        if opt.kind == params.BOOL:
            action = "store_false" if opt.default is True else "store_true"
            parser.add_argument(*flags, dest=name, action=action, default=default, help=text.replace("%", "%%"))
            continue
        if default is not None:
            shown = ",".join(default) if isinstance(default, (list, tuple)) else default
            text += f" (default {shown})"
        metavar = opt.metavar
        if metavar is None and opt.kind in (params.CHOICE, params.FORMAT):
            metavar = "{" + ",".join(opt.choices) + "}"
        kind = _TYPES.get(opt.kind, str)
        parser.add_argument(*flags, dest=name, type=parse_numbers(kind) if opt.many else kind, default=default,
                            metavar=metavar or name.upper(), help=text.replace("%", "%%"))


def option_values(args: argparse.Namespace, command: str, names: Iterable[str] | None = None, *,
                  check: bool = False) -> dict[str, Any]:
    """The options of *command* found in *args*, as API keyword arguments; validated and normalised with *check*."""
    spec = params.COMMANDS[command]
    values = {n: getattr(args, n) for n in (names if names is not None else spec) if hasattr(args, n)}
    if check:
        normalised = params.validate(command, values)
        values = {n: normalised[n] for n in values}
    return values



def flag_wording(name: str, value: Any) -> str:
    """The command line's words for option *name* set to *value*: ``--overwrite``, ``--no-strict``, ``--seed 3``."""
    option = params.OPTIONS[name]
    dashed = name.replace("_", "-")
    if option.kind == params.BOOL and isinstance(value, bool):
        return f"--{dashed}" if value else f"--no-{dashed}"
    return f"--{dashed} {value}"


def cli_message(exc: CloudsieveError, wording: Callable[[str, Any], str] = flag_wording) -> str:
    """The message of *exc* with the options it advises worded for the command line.
    The options in ``exc.advice`` (``overwrite=True``) become ``wording(name, value)``: flags, or a pipeline
    stage's key under ``cloudsieve run``. With flags, the options named in ``exc.options`` become flags too and
    ``exc.caller`` (``cloudsieve.simplify``) the command."""
    message = str(exc)
    for name, value in getattr(exc, "advice", {}).items():
        message = message.replace(f"{name}={value!r}", wording(name, value))
    caller = getattr(exc, "caller", None)
    if caller and caller.startswith("cloudsieve."):  # the API's name: cloudsieve.simplify -> cloudsieve simplify
        message = message.replace(caller, caller.replace(".", " ", 1))
    if wording is flag_wording:  # the options the message names as words, as flags (a pipeline's keys stay)
        for name in getattr(exc, "options", ()):
            message = re.sub(rf"(?<![\w-]){re.escape(name)}(?![\w=])", "--" + name.replace("_", "-"), message)
    return message


@contextlib.contextmanager
def task_runner(label: str, total: int | None, no_progress: bool) -> Iterator[tuple[Any, Callable[[int], None]]]:
    """(the local worker processes of a command's tasks (ingest, export), one bar per stage; the command's own
    bar *label* of *total* points, its ``update(n)``); both closed on exit."""
    from .. import progress
    from ..engine.runner import Runner

    runner = Runner(bars=lambda stage, n, unit: progress.bar(stage, n, unit=unit, enabled=not no_progress))
    try:
        with progress.bar(label, total, enabled=not no_progress) as update:
            yield runner, update
    finally:
        runner.close()
