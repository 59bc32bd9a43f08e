"""One option's value checked: :func:`check` (each kind of :mod:`cloudsieve.params_spec`), and :func:`named`,
which marks the options an error names (the command line writes them as flags). A leaf, as :mod:`cloudsieve.params`."""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from .address import host_port
from .errors import InvalidParameterError
from .params_spec import (BOOL, CHOICE, CHOICES, CLASS_RATIOS, CLASSES, FLOAT, FORMAT, INT, JSON, LOCAL_SCHEDULERS,
                          OPTIONS, PATH, SIZE, TEXT, Option)

__all__ = ["named", "check"]


def named(exc: InvalidParameterError, *names: str) -> InvalidParameterError:
    """*exc* with the options its message names as words (``ratio must be ...``): the command line
    writes each as its flag (:func:`cloudsieve.cli._common.cli_message`). Kept in ``__dict__``
    (it survives pickling)."""
    exc.options = names
    return exc


def _refuse(option: Option, value: Any) -> InvalidParameterError:
    return named(InvalidParameterError(f"{option.name} must be {option.describe()}, got {value!r}"), option.name)


def _number(option: Option, value: Any) -> float | int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise _refuse(option, value)
    if option.kind == INT:
        if not float(value).is_integer():  # 1e6 from JSON is an integer; 2.5 is not
            raise _refuse(option, value)
        value = int(value)
    else:
        value = float(value)
        if not math.isfinite(value):
            raise _refuse(option, value)
    low, high = option.low, option.high
    if low is not None and (value < low or (option.low_open and value == low)):
        raise _refuse(option, value)
    if high is not None and value > high:
        raise _refuse(option, value)
    return value


def _numbers(option: Option, value: Any) -> float | int | tuple:
    """A number, or a list of them in decreasing order (a tuple of two or more; one value: that number)."""
    if not isinstance(value, (list, tuple)):
        return _number(option, value)
    if not value:
        raise _refuse(option, value)
    values = [_number(option, v) for v in value]
    twice = sorted({v for v in values if values.count(v) > 1})
    if twice:
        raise named(InvalidParameterError(f"{option.name} lists {twice[0]:g} more than once: each output needs its "
                                          f"own {option.name}"), option.name)
    values.sort(reverse=True)  # each output a subset of the one before
    return values[0] if len(values) == 1 else tuple(values)


def _scheduler(option: Option, value: Any) -> str:
    if not isinstance(value, str):
        raise _refuse(option, value)
    if "://" in value:
        host_port(value)  # a tcp:// address needs a host and a port
    elif value not in LOCAL_SCHEDULERS:
        raise InvalidParameterError(
            f"unknown scheduler {value!r}: use sync, threads, processes or a tcp://host:port address")
    return value


def _size(option: Option, value: Any) -> int | str:
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)) and value >= 1:
        return int(value)
    if isinstance(value, str):
        if value == "auto":
            return value
        from dask.utils import parse_bytes

        try:
            if parse_bytes(value) >= 1:
                return value
        except (ValueError, TypeError):
            pass
    raise _refuse(option, value)


def _json(option: Option, value: Any) -> dict:
    """A dict, or JSON text of an object (the command line's form). The message never shows the value: it
    may hold credentials."""
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except ValueError as exc:
            raise named(InvalidParameterError(f"{option.name} must be a JSON object: {exc.msg} at character "
                                              f"{exc.pos}"), option.name) from None
    if not isinstance(value, dict):
        raise named(InvalidParameterError(f"{option.name} must be a JSON object (a dict), got "
                                          f"{type(value).__name__}"), option.name)
    return value


def _choices(option: Option, value: Any) -> list[str]:
    items = value.split(",") if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not all(isinstance(v, str) for v in items):
        raise _refuse(option, value)
    items = [v.strip() for v in items if v.strip()]
    bad = [v for v in items if v not in option.choices]
    if bad or not items:
        singular = option.name[:-1] if option.name.endswith("s") else option.name
        raise InvalidParameterError(f"unknown {singular}(s) {bad or items}; choose among {', '.join(option.choices)}")
    return items


def _code(option: Option, item: Any) -> int:
    """One LAS classification code of *option*: an integer 0..255 (text from the command line)."""
    text = item.strip() if isinstance(item, str) else item
    if isinstance(text, str) and text.lstrip("-").isdigit():
        text = int(text)
    if isinstance(text, (bool, np.bool_)) or not isinstance(text, numbers.Integral):
        raise named(InvalidParameterError(f"{option.name}: {item!r} is not a class code (an integer 0..255)"),
                    option.name)
    if not 0 <= int(text) <= 255:
        raise named(InvalidParameterError(f"{option.name}: class code {int(text)} is out of 0..255"), option.name)
    return int(text)


def _items(option: Option, value: Any) -> list:
    """The items of a comma-separated text, a list or (class ratios) a dict's pairs; none is an error."""
    if isinstance(value, str):
        items = [v for v in value.split(",") if v.strip()]
    elif isinstance(value, Mapping) and option.kind == CLASS_RATIOS:
        items = list(value.items())
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        raise _refuse(option, value)
    if not items:
        raise _refuse(option, value)
    return items


def _classes(option: Option, value: Any) -> list[int]:
    """LAS classification codes, sorted, each once: ``"2,9"`` or ``[2, 9]`` -> ``[2, 9]``."""
    return sorted({_code(option, item) for item in _items(option, value)})


def _class_ratios(option: Option, value: Any) -> list[list]:
    """``[[code, ratio], ...]`` sorted by code from ``"5=0.1,2=1.0"``, ``{5: 0.1}`` or pairs; a code once."""
    out: dict[int, float] = {}
    for item in _items(option, value):
        pair = item.split("=") if isinstance(item, str) else item
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise named(InvalidParameterError(f"{option.name}: {item!r} is not CODE=RATIO (e.g. 5=0.1)"),
                        option.name)
        code, ratio = _code(option, pair[0]), pair[1]
        try:
            ratio = float(ratio.strip()) if isinstance(ratio, str) else ratio
        except ValueError:
            ratio = pair[1]
        if isinstance(ratio, (bool, np.bool_)) or not isinstance(ratio, numbers.Real) or not 0 < ratio <= 1:
            raise named(InvalidParameterError(f"{option.name}: the ratio of class {code} must be a number in "
                                              f"(0, 1], got {pair[1]!r}"), option.name)
        if code in out and out[code] != float(ratio):
            raise named(InvalidParameterError(f"{option.name}: class {code} is given two ratios, {out[code]:g} and "
                                              f"{float(ratio):g}"), option.name)
        out[code] = float(ratio)
    return [[code, out[code]] for code in sorted(out)]


#: the kinds whose values a function of their own checks
_PARSERS = {CHOICES: _choices, SIZE: _size, JSON: _json, CLASSES: _classes, CLASS_RATIOS: _class_ratios}


def check(option: Option | str, value: Any) -> Any:
    """Validate one value of *option*; returns it normalised (None where the default is None).
    Raises InvalidParameterError ``"<name> must be <what>, got <value>"``."""
    if isinstance(option, str):
        option = OPTIONS[option]
    if value is None and option.default is None:
        return None
    kind = option.kind
    if kind in (INT, FLOAT):
        return _numbers(option, value) if option.many else _number(option, value)
    if kind == BOOL:
        if not isinstance(value, (bool, np.bool_)):
            raise _refuse(option, value)
        return bool(value)
    if kind in (CHOICE, FORMAT):
        if not isinstance(value, str) or (value.lower().lstrip(".") if kind == FORMAT else value) not in option.choices:
            raise _refuse(option, value)
        return value
    if kind in _PARSERS:
        return _PARSERS[kind](option, value)
    if kind == PATH and isinstance(value, os.PathLike):
        return os.fspath(value)
    if kind in (TEXT, PATH):
        if not isinstance(value, str) or not value:
            raise _refuse(option, value)
        return value
    return _scheduler(option, value)
