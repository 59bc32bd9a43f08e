"""Parsing blocks of text rows into numbers, naming the line of a bad row."""

from __future__ import annotations

import numpy as np

from ..errors import CorruptInputError

__all__ = ["parse_rows"]


def _bad_row(lines: list[tuple[int, str]], ncols: int, path: str, split) -> CorruptInputError:
    for lineno, line in lines:
        tokens = split(line)
        if len(tokens) != ncols:
            return CorruptInputError(
                f"{path}, line {lineno}: expected {ncols} values, found {len(tokens)}: {line.strip()[:80]!r}"
            )
        for tok in tokens:
            try:
                float(tok)
            except ValueError:
                return CorruptInputError(f"{path}, line {lineno}: cannot read {tok!r} as a number: {line.strip()[:80]!r}")
    return CorruptInputError(f"{path}: cannot parse rows {lines[0][0]}-{lines[-1][0]}")  # pragma: no cover


def parse_rows(lines: list[tuple[int, str]], ncols: int, path: str, delimiter: str | None = None) -> np.ndarray:
    """Parse ``[(line_number, text), ...]`` into a float64 array of shape (n, ncols).

    *delimiter* None splits on whitespace. Raises CorruptInputError naming
    the first bad line (wrong number of values, or a value that is not a
    number).
    """

    def split(line: str) -> list[str]:
        if delimiter is None:
            return line.split()
        return [t.strip() for t in line.strip().split(delimiter)]

    if delimiter is None:
        tokens = " ".join(text for _, text in lines).split()
    else:
        tokens = delimiter.join(text.strip() for _, text in lines).split(delimiter)
        tokens = [t.strip() for t in tokens]
    if len(tokens) != len(lines) * ncols:
        raise _bad_row(lines, ncols, path, split)
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        raise _bad_row(lines, ncols, path, split) from None
    return values.reshape(len(lines), ncols)
