"""The out-of-core run on dask: partition, cells, merge, export.

Each name is imported at its first use (PEP 562): a small input's run
(:mod:`.small`) imports none of the stages' modules.
"""

from __future__ import annotations

import importlib

from ..lazy import keep_functions

#: where each public name lives (a module of this package)
_LAZY = {"simplify": ".simplify", "Summary": ".summary", "DEFAULT_SCHEDULER": ".runner", "SIMPLIFY_ATTR": ".workstore",
         "cell_seed": ".cells"}

__all__ = ["simplify", "Summary", "DEFAULT_SCHEDULER", "SIMPLIFY_ATTR", "cell_seed"]


def __getattr__(name: str):
    """A public name of :data:`_LAZY`, imported from its module at its first use."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


# simplify is always the function, never the module of the same name
keep_functions(__name__, __getattr__, {"simplify": "simplify"})
