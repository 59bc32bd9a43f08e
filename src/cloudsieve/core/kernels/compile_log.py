"""What numba compiles, kernel by kernel: :class:`CompileLog`.

Built on numba's ``"numba:compile"`` events (not cache loads); a kernel's time
excludes its callees', so rows add up to the whole.
"""

from __future__ import annotations

import time
from collections import defaultdict

__all__ = ["CompileLog"]


class CompileLog:
    """Records the seconds numba spends compiling each kernel while the block runs.

    Attributes
    ----------
    seconds : dict of str to float
        Compile seconds per kernel (``module.function``), callees excluded.
    signatures : dict of str to int
        Signatures compiled per kernel.

    Examples
    --------
    >>> with CompileLog() as log:  # doctest: +SKIP
    ...     kernel(np.zeros(3))
    >>> log.seconds  # doctest: +SKIP
    {'cloudsieve.core.kernels.x.kernel': 1.92}
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.signatures: dict[str, int] = defaultdict(int)
        self._stack: list[list[float]] = []  # [start, seconds of the callees]
        self._listener = None

    def __enter__(self) -> CompileLog:
        from numba.core import event

        log = self

        class _Listener(event.Listener):
            def on_start(self, ev) -> None:
                log._stack.append([time.perf_counter(), 0.0])

            def on_end(self, ev) -> None:
                start, inner = log._stack.pop()
                spent = time.perf_counter() - start
                if log._stack:
                    log._stack[-1][1] += spent
                d = ev.data["dispatcher"]
                name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
                log.seconds[name] += spent - inner
                log.signatures[name] += 1

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)

    @property
    def total(self) -> float:
        """All compile seconds recorded."""
        return float(sum(self.seconds.values()))
