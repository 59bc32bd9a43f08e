"""numba's BLAS probe, skipped in the package's own processes (the command, the local fork server).

The first kernel numba loads from its cache (or compiles) imports
``numba.np.arraymath``, which at import checks that ``np.dot`` could call
BLAS by importing ``scipy.linalg.cython_blas``: all of ``scipy.linalg``, with
a second OpenBLAS and its threads. No compiled kernel of this package calls
``np.dot``, ``np.vdot``, ``@`` or ``np.linalg`` (tests/test_speed_start.py
reads their sources), and a run of the default rule imports nothing else of
``scipy.linalg``. On this project's test machine, the first kernel load of a
process took 0.26-0.31 s with the probe skipped, against 0.48-0.58 s, of a
1,065-point file's whole run of about 1 s (docs/benchmarks.md).

:func:`skip_blas_probe` installs an import hook that, while
``numba.np.arraymath`` and only it is executed, makes the probe's import fail
at once (numba then takes BLAS as absent: an ``np.dot`` compiled later in the
process would be numba's loop), then removes itself: ``scipy.linalg`` imports
as usual afterwards (``evaluate``'s k-d trees). A process that had imported
``scipy.linalg`` already keeps the probe (it costs nothing there). Not for a
process that is not the package's: user code in it may compile ``np.dot``.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys

__all__ = ["skip_blas_probe"]

_ARRAYMATH = "numba.np.arraymath"
_PROBE = "scipy.linalg.cython_blas"


class _Loader(importlib.abc.Loader):
    """The module's own loader, executing it with the probe's import blocked."""

    def __init__(self, loader):
        self._loader = loader

    def __getattr__(self, name):  # get_source, get_filename, is_package...: the real loader's
        return getattr(self._loader, name)

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        block = "scipy.linalg" not in sys.modules and _PROBE not in sys.modules
        if block:
            sys.modules[_PROBE] = None  # import raises ImportError: numba's _HAVE_BLAS is False
        try:
            self._loader.exec_module(module)
        finally:
            if block and _PROBE in sys.modules and sys.modules[_PROBE] is None:
                del sys.modules[_PROBE]


class _Finder(importlib.abc.MetaPathFinder):
    """Finds ``numba.np.arraymath`` as the path finder would, with :class:`_Loader` around its loader; once."""

    def find_spec(self, name, path, target=None):
        if name != _ARRAYMATH:
            return None
        _remove()
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _Loader(spec.loader)
        return spec


_FINDER = _Finder()


def _remove() -> None:
    if _FINDER in sys.meta_path:
        sys.meta_path.remove(_FINDER)


def skip_blas_probe() -> None:
    """Skip numba's BLAS probe in this process (module docstring); nothing if numba's module is loaded."""
    if _ARRAYMATH not in sys.modules and _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)
