"""Packages that import their names at first use (PEP 562): a leaf, imported by the packages' ``__init__``.

:func:`lazy_names` gives a package the ``__getattr__`` and ``__dir__`` that
import each public name from its module when it is first asked for, so a run
imports only the modules it uses (a small input's run no zarr, dask or
stages: ``cloudsieve.store``, ``cloudsieve.engine``).

Importing a submodule binds it as an attribute of its package, which would
hide the function of the same name that the package imports at first use
(``cloudsieve.evaluate``, ``cloudsieve.store.export``,
``cloudsieve.engine.simplify``). :func:`keep_functions` gives the package a
module type whose properties always answer the function, and ignore the
import system's binding.
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
