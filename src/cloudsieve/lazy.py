"""Packages that import their names at first use (PEP 562): a leaf, imported by the packages' ``__init__``.

:func:`lazy_names` gives a package ``__getattr__`` and ``__dir__`` importing each public name at its
first use, so a run imports only what it uses. Importing a submodule binds it over the package's
function of the same name (``cloudsieve.evaluate``, ``cloudsieve.store.export``,
``cloudsieve.engine.simplify``): :func:`keep_functions` makes the package always answer the function.
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Callable

__all__ = ["lazy_names", "keep_functions"]


def lazy_names(package: str, names: dict[str, str]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """PEP 562 ``__getattr__`` and ``__dir__`` of *package*: each name of *names* imported from its module
    (relative to *package*) at its first use, then a plain attribute."""

    def __getattr__(name: str):
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
            vars(sys.modules[package])[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *names})

    return __getattr__, __dir__


def keep_functions(package: str, getter: Callable[[str], object], names: dict[str, str]) -> None:
    """Make ``package.NAME`` always ``getter(names[NAME])`` for each NAME of *names*."""
    props = {name: property(lambda self, key=key: getter(key), lambda self, module: None)
             for name, key in names.items()}
    sys.modules[package].__class__ = type("_Package", (types.ModuleType,), props)
