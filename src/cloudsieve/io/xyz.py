"""XYZ / TXT / CSV / PTS text clouds: one point per row, in blocks of rows.

Reading: the delimiter is given or sniffed (comma, semicolon, else whitespace). A first row with a non-numeric
value names the columns (a leading ``#`` or ``//`` stripped); a first row of one integer (PTS count) is skipped;
``columns=[...]`` and ``skiprows=k`` override. Unnamed columns are ``x y z`` + ``intensity`` (4), ``red green
blue`` (6), ``intensity red green blue`` (7, PTS), else ``col3, ...``; ``x``, ``y``, ``z`` (any case) are
required. An attribute column is int64 when its values in the first :data:`TYPED_ROWS` rows are integer
literals, else float64. Blank and ``#``/``//`` lines are skipped; a bad row raises CorruptInputError naming its
line. ``count`` is None until read.

Writing: a header row, then one row per point, space separated (comma for .csv); floats as their shortest
round-tripping text, always with ``.`` or an exponent; (n, k) attributes as ``name_0 .. name_{k-1}``.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..errors import InputFormatError
from ..chunk import DEFAULT_CHUNK_SIZE
from ._base import Reader, Writer
from ._text import is_integer, parse_typed_rows, split_row

__all__ = ["XyzReader", "XyzWriter", "TYPED_ROWS"]

#: data rows whose values decide which attribute columns are integers
TYPED_ROWS = 10_000

logger = logging.getLogger(__name__)

_DEFAULT_COLUMNS = {
    3: ["x", "y", "z"],
    4: ["x", "y", "z", "intensity"],
    6: ["x", "y", "z", "red", "green", "blue"],
    7: ["x", "y", "z", "intensity", "red", "green", "blue"],
}


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _is_comment(line: str) -> bool:
    s = line.lstrip()
    return not s or s.startswith("#") or s.startswith("//")


class XyzReader(Reader):
    """Block reader of text point clouds; options ``delimiter``, ``columns``, ``skiprows`` (module docstring)."""

    def __init__(self, path: str, format: str, chunk_size: int = DEFAULT_CHUNK_SIZE, **options: Any) -> None:
        super().__init__(path, format, chunk_size, **options)
        self._delimiter = options.get("delimiter")
        columns = options.get("columns")
        skip = int(options.get("skiprows", 0))
        header_line = None
        header_comment = False
        first_data = None
        lineno = 0
        with open(path, encoding="utf-8", errors="replace") as fh:
            lines = iter(fh)
            for line in itertools.islice(lines, skip):
                lineno += 1
            for line in lines:
                lineno += 1
                stripped = line.strip()
                if not stripped:
                    continue
                if stripped.startswith("#") or stripped.startswith("//"):
                    body = stripped.lstrip("#/").strip()
                    if header_line is None and first_data is None and body and not _is_number(body.split()[0]):
                        header_line = (lineno, body)
                        header_comment = True
                    continue
                if self._delimiter is None:
                    self._delimiter = "," if "," in stripped else (";" if ";" in stripped else None)
                tokens = split_row(stripped, self._delimiter)
                if not all(_is_number(t) for t in tokens) and (header_line is None or header_comment):
                    header_line = (lineno, stripped)  # a header row of column names
                    header_comment = False
                    continue
                if len(tokens) == 1 and tokens[0].isdigit() and "pts_count" not in self.header:
                    self.header["pts_count"] = int(tokens[0])  # PTS: first line is the count
                    continue
                first_data = (lineno, stripped)
                break
        if first_data is None and header_line is None:
            self._names = columns or ["x", "y", "z"]
            self._start = lineno + 1
        else:
            ncols = len(split_row(first_data[1], self._delimiter)) if first_data else None
            if header_comment and ncols is not None and len(split_row(header_line[1], self._delimiter)) != ncols:
                header_line = None  # a comment, not column names
            if columns is None and header_line is not None:
                columns = [c for c in split_row(header_line[1], self._delimiter) if c]
            if columns is None:
                columns = _DEFAULT_COLUMNS.get(ncols) or ["x", "y", "z"] + [f"col{i}" for i in range(3, ncols or 3)]
            if ncols is not None and len(columns) != ncols:
                raise InputFormatError(
                    f"{path}, line {first_data[0]}: {ncols} values but {len(columns)} column names ({', '.join(columns)})"
                )
            self._names = list(columns)
            self._start = first_data[0] if first_data else lineno + 1
        lower = [c.lower() for c in self._names]
        missing = [c for c in "xyz" if c not in lower]
        if missing:
            raise InputFormatError(f"{path}: text cloud has no {'/'.join(missing)} column (columns: {', '.join(self._names)})")
        self._xyz_index = [lower.index(c) for c in "xyz"]
        self._attr = [(i, n) for i, n in enumerate(self._names) if i not in self._xyz_index]
        self._integers = self._integer_columns(path)
        for i, name in self._attr:
            self.dtypes[name] = (np.dtype(np.int64 if i in self._integers else np.float64), ())
        self.header.update({"columns": self._names, "delimiter": self._delimiter})
        self.count = None

    def _data_rows(self) -> Iterator[tuple[int, str]]:
        """(line number, text) of every data row, from the first on."""
        with open(self.path, encoding="utf-8", errors="replace") as fh:
            numbered = enumerate(fh, start=1)
            for _ in itertools.islice(numbered, self._start - 1):
                pass
            yield from ((i, line) for i, line in numbered if not _is_comment(line))

    def _integer_columns(self, path: str) -> dict[int, str]:
        """Attribute columns (index -> name) whose values in the first TYPED_ROWS data rows are all integers."""
        candidates, seen = dict(self._attr), False
        for _, line in itertools.islice(self._data_rows(), TYPED_ROWS):
            seen = True
            tokens = split_row(line, self._delimiter)
            if len(tokens) != len(self._names):
                continue  # a bad row: the read names it
            for i in [i for i in candidates if not is_integer(tokens[i])]:
                del candidates[i]
            if not candidates:
                break
        return candidates if seen else {}

    def _read_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Blocks of at most ``chunk_size`` rows, as dicts."""
        ncols = len(self._names)
        rows = self._data_rows()
        while True:
            block = list(itertools.islice(rows, self.chunk_size))
            if not block:
                break
            values, ints = parse_typed_rows(block, ncols, self.path, self._delimiter, self._integers, TYPED_ROWS)
            chunk = {"xyz": np.ascontiguousarray(values[:, self._xyz_index])}
            for i, name in self._attr:
                chunk[name] = ints[i] if i in ints else np.ascontiguousarray(values[:, i])
            yield chunk


class XyzWriter(Writer):
    """Text writer: header row, then one row per point."""

    def _open(self) -> None:
        self._delimiter = "," if self.path.lower().endswith(".csv") else " "
        names = ["x", "y", "z"]
        fmts = ["%r"] * 3  # a Python float's repr: the shortest text of the same value, with "." or "e"
        self._cols: list[tuple[str, int | None]] = []
        self._float32: set[str] = set()  # columns written from numpy float32 scalars (their shortest text)
        for name, (dtype, shape) in self.dtypes.items():
            if name == "xyz":
                continue
            if dtype.kind in "iub":
                fmt = "%d"
            elif dtype == np.float32:
                fmt = "%s"
                self._float32.add(name)
            elif dtype.kind == "f":
                fmt = "%r"
            else:
                logger.warning("%s: attribute %r of type %s not written", self.path, name, dtype)
                continue
            if shape == ():
                names.append(name)
                fmts.append(fmt)
                self._cols.append((name, None))
            elif len(shape) == 1:
                for i in range(shape[0]):
                    names.append(f"{name}_{i}")
                    fmts.append(fmt)
                    self._cols.append((name, i))
        self._fmt = self._delimiter.join(fmts)
        self.file.write((self._delimiter.join(names) + "\n").encode())

    def _write(self, chunk: dict[str, np.ndarray]) -> None:
        xyz = np.asarray(chunk["xyz"], dtype=np.float64)
        values = [xyz[:, 0].tolist(), xyz[:, 1].tolist(), xyz[:, 2].tolist()]
        for name, i in self._cols:
            c = np.asarray(chunk[name] if i is None else chunk[name][:, i])
            values.append(list(c.astype(np.float32, copy=False)) if name in self._float32 else c.tolist())
        fmt = self._fmt
        text = "\n".join(fmt % row for row in zip(*values))
        self.file.write((text + "\n").encode())
