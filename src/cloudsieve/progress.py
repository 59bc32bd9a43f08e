"""Progress reporting: library code takes a callback, the CLI shows a bar.

Library functions accept ``progress=None`` or a callable ``progress(n)`` called
with the number of points (or tasks) just finished; they never print. The CLI
builds the callable from a tqdm bar with :func:`bar`.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator

ProgressCallback = Callable[[int], None]


def _noop(n: int) -> None:
    pass


def callback(progress: ProgressCallback | None) -> ProgressCallback:
    """Return *progress*, or a no-op when it is None."""
    return progress if progress is not None else _noop


@contextlib.contextmanager
def bar(desc: str, total: int | None, unit: str = "pt", enabled: bool = True) -> Iterator[ProgressCallback]:
    """A tqdm progress bar on stderr, yielded as an ``update(n)`` callback.

    Disabled (a no-op) when *enabled* is False or stderr is not a terminal.
    """
    if not enabled or not sys.stderr.isatty():
        yield _noop
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit=unit, unit_scale=True, file=sys.stderr, dynamic_ncols=True) as t:
        yield t.update
