"""Packages whose public functions share a name with one of their submodules (``cloudsieve.evaluate``,
``cloudsieve.store.export``): a leaf, imported by the packages' ``__init__``.

Importing a submodule binds it as an attribute of its package, which would
hide the function of the same name that the package imports at first use
(PEP 562 ``__getattr__``). :func:`keep_functions` gives the package a module
type whose properties always answer the function, and ignore the import
system's binding.
"""

from __future__ import annotations

import sys
import types
from collections.abc import Callable

__all__ = ["keep_functions"]


def keep_functions(package: str, getter: Callable[[str], object], names: dict[str, str]) -> None:
    """Make ``package.NAME`` always ``getter(names[NAME])`` for each NAME of *names*."""
    props = {name: property(lambda self, key=key: getter(key), lambda self, module: None)
             for name, key in names.items()}
    sys.modules[package].__class__ = type("_Package", (types.ModuleType,), props)
