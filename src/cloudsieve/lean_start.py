"""What the package's own processes (the command, the local fork server) skip at start.

:func:`skip_unused_imports` installs an import hook that, while each module alone executes, blocks what it
imports and a run never uses: ``numba``'s scipy (a version check), ``numba.core.config``'s yaml (without a
``.numba_config.yaml`` here), ``numba.np.arraymath``'s ``scipy.linalg`` (a BLAS probe for ``np.dot``, which no
kernel here uses: tests/test_speed_start.py), ``laspy.copc``'s ``requests`` and ``laspy.vlrs.geotiff``'s
``pyproj``. numba's cache loads initialise the runtime (NRT) alone instead of every compiler registry
(:func:`load_without_registries`); a compilation still refreshes them. Why: docs/architecture.md, "Design
reasons". Not for other processes: their code may compile ``np.dot`` or read COPC over HTTP.
"""

from __future__ import annotations

import importlib.machinery
import os
import sys
from typing import Callable, NamedTuple

__all__ = ["skip_unused_imports", "load_without_registries", "MODULES"]


def load_without_registries(caching) -> None:
    """Make the cache loads of numba's module *caching* (``numba.core.caching``) initialise numba's runtime
    instead of refreshing the target context (module docstring). A numba without the private methods this
    relies on (``Cache._load_overload``, ``Cache._guard_against_spurious_io_errors``) is left as it is."""
    cache = getattr(caching, "Cache", None)
    if not all(hasattr(cache, m) for m in ("load_overload", "_load_overload", "_guard_against_spurious_io_errors")):
        return

    def load_overload(self, sig, target_context):
        from numba.core.runtime import rtsys

        rtsys.initialize(target_context)  # what a loaded kernel needs of the refresh: NRT's allocator
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload.__doc__ = cache.load_overload.__doc__
    cache.load_overload = load_overload


class Change(NamedTuple):
    """What is done to one module: the import skipped while it is executed (``blocked``, None: none), unless
    ``loaded`` is present (then that import is free) or ``when`` (a test at its import) fails; and ``after``,
    called with the module once it is executed (or at once, when it is already loaded)."""

    blocked: str | None = None
    loaded: str | None = None
    when: Callable[[], bool] | None = None
    after: Callable[[object], None] | None = None


def _no_numba_config() -> bool:
    return not os.path.isfile(".numba_config.yaml")  # numba's config file in the working folder, read by yaml


#: the module executed -> what is done to it (module docstring)
MODULES = {
    "numba": Change("scipy", "scipy"),
    "numba.core.config": Change("yaml", "yaml", when=_no_numba_config),
    "numba.core.caching": Change(after=load_without_registries),
    "numba.np.arraymath": Change("scipy.linalg.cython_blas", "scipy.linalg"),
    "laspy.copc": Change("requests", "requests"),
    "laspy.vlrs.geotiff": Change("pyproj", "pyproj"),
}


class _Loader:
    """A module's own loader, executing it with its :class:`Change` (the protocol of ``importlib.abc.Loader``,
    whose own import pulls in ``importlib.resources``, a cost of its own)."""

    def __init__(self, loader, change: Change):
        self._loader, self._change = loader, change

    def __getattr__(self, name):  # get_source, get_filename, is_package...: the real loader's
        return getattr(self._loader, name)

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        blocked, loaded, when, after = self._change
        block = (blocked is not None and loaded not in sys.modules and blocked not in sys.modules
                 and (when is None or when()))
        if block:
            sys.modules[blocked] = None  # its import raises ImportError (ModuleNotFoundError)
        try:
            self._loader.exec_module(module)
        finally:
            if block and blocked in sys.modules and sys.modules[blocked] is None:
                del sys.modules[blocked]
        if after is not None:
            after(module)


class _Finder:
    """Finds each module of ``MODULES`` as the path finder would, with :class:`_Loader` around its loader;
    once each, and gone from ``sys.meta_path`` after the last."""

    def __init__(self):
        self.left = set()

    def find_spec(self, name, path, target=None):
        if name not in self.left:
            return None
        self.left.discard(name)
        if not self.left and self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _Loader(spec.loader, MODULES[name])
        return spec


_FINDER = _Finder()


def skip_unused_imports() -> None:
    """Make, in this process, the changes of ``MODULES`` (module docstring): at their import for the modules
    not loaded yet; for those already loaded, the ``after`` changes at once (their imports are done)."""
    for name, change in MODULES.items():
        if name in sys.modules and change.after is not None:
            change.after(sys.modules[name])
    _FINDER.left = {name for name in MODULES if name not in sys.modules}
    if _FINDER.left and _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)
