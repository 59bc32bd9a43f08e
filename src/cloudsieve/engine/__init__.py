"""The out-of-core run on dask; names import at first use (PEP 562), so a small input's run imports no stage."""

from __future__ import annotations

from ..lazy import keep_functions, lazy_names

#: where each public name lives (a module of this package)
_LAZY = {"simplify": ".simplify", "Summary": ".summary", "DEFAULT_SCHEDULER": ".runner", "SIMPLIFY_ATTR": ".workstore",
         "cell_seed": ".cells"}

__all__ = list(_LAZY)


__getattr__, __dir__ = lazy_names(__name__, _LAZY)

# simplify is always the function, never the module of the same name
keep_functions(__name__, __getattr__, {"simplify": "simplify"})
