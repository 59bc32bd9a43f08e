"""Parsing blocks of text rows into numbers, naming the line of a bad row."""

from __future__ import annotations

import functools
import re

import numpy as np

from ..errors import CorruptInputError

__all__ = ["parse_rows", "parse_typed_rows", "is_integer", "split_row"]

_INTEGER = re.compile(r"[+-]?\d{1,18}")  # 18 digits: within int64


def is_integer(token: str) -> bool:
    """True when *token* is an integer literal of int64 (at most 18 digits, an optional sign): no decimal point,
    exponent, nan or inf."""
    return _INTEGER.fullmatch(token) is not None


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


def split_row(line: str, delimiter: str | None) -> list[str]:
    """The values of one text row: split on whitespace (*delimiter* None) or on *delimiter*, each stripped."""
    if delimiter is None:
        return line.split()
    return [t.strip() for t in line.strip().split(delimiter)]


def _tokens(lines: list[tuple[int, str]], ncols: int, path: str, delimiter: str | None) -> tuple[list[str], object]:
    split = functools.partial(split_row, delimiter=delimiter)
    if delimiter is None:
        tokens = " ".join(text for _, text in lines).split()
    else:
        tokens = delimiter.join(text.strip() for _, text in lines).split(delimiter)
        tokens = [t.strip() for t in tokens]
    if len(tokens) != len(lines) * ncols:
        raise _bad_row(lines, ncols, path, split)
    return tokens, split


def parse_rows(lines: list[tuple[int, str]], ncols: int, path: str, delimiter: str | None = None) -> np.ndarray:
    """Parse ``[(line_number, text), ...]`` into a float64 array of shape (n, ncols).
    *delimiter* None splits on whitespace. Raises CorruptInputError naming the first bad line (wrong number of
    values, or a value that is not a number)."""
    tokens, split = _tokens(lines, ncols, path, delimiter)
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        raise _bad_row(lines, ncols, path, split) from None
    return values.reshape(len(lines), ncols)


def parse_typed_rows(lines: list[tuple[int, str]], ncols: int, path: str, delimiter: str | None,
                     integers: dict[int, str], typed_rows: int) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """:func:`parse_rows`, and the columns *integers* (index -> name) as int64 arrays.
    A value of an integer column may be written as a float of no fraction (``3.0``); one with a fraction raises
    CorruptInputError naming its line and saying that the column's first *typed_rows* rows made it integers."""
    tokens, split = _tokens(lines, ncols, path, delimiter)
    try:
        values = np.array(tokens, dtype=np.float64).reshape(len(lines), ncols)
    except ValueError:
        raise _bad_row(lines, ncols, path, split) from None
    out = {}
    for col, name in integers.items():
        try:
            out[col] = np.array(tokens[col::ncols], dtype=np.int64)
        except (ValueError, OverflowError):
            v = values[:, col]
            whole = np.isfinite(v) & (v == np.trunc(v)) & (np.abs(v) < 2.0**63)
            if not whole.all():
                row = int(np.flatnonzero(~whole)[0])
                raise CorruptInputError(
                    f"{path}, line {lines[row][0]}: column {name} holds {tokens[row * ncols + col]!r}, not an integer of 64 bits, "
                    f"but its first {typed_rows:,} rows hold integers only, so it is read as integers; write one of "
                    f"those with a decimal point (1.0) to read the column as floats") from None
            out[col] = v.astype(np.int64)
    return values, out
