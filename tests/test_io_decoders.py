"""Every decoder of point records is in io/: no module outside it calls laspy's or lazrs' reading entry points.

The source is read with ``ast``, nothing is imported. A reading entry point is
``laspy.open`` (but for writing, ``mode="w"`` or ``"a"``), ``laspy.read``,
``laspy.mmap``, ``laspy.LasReader``, lazrs' decompressors and chunk-table
readers, and the reader methods ``read_points`` and ``chunk_iterator``. The
writers stay where they write: the COPC writer (store/copc_file.py) and the LAS
export's splice (store/export_las.py) call lazrs' compressor and
``write_chunk_table``, the example scan (synthetic.py) ``laspy.open(mode="w")``.

``EXPECTED`` lists the known exceptions, each with its reason; an entry that no
longer occurs fails the test too, so the list stays exact.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "cloudsieve"

#: the reading entry points, by module
READERS = {
    "laspy": {"open", "read", "mmap", "LasReader"},
    "lazrs": {"decompress_points", "decompress_points_with_chunk_table", "LasZipDecompressor",
              "ParLasZipDecompressor", "read_chunk_table", "read_chunk_table_only"},
}
#: reader methods (of a laspy reader)
METHODS = {"read_points", "chunk_iterator"}
#: known exceptions (module, entry point): each must occur, or the test fails
EXPECTED: set[tuple[str, str]] = set()


def _writes(call: ast.Call) -> bool:
    """``laspy.open(..., mode="w")`` (or ``"a"``, or the mode as second argument)."""
    modes = [k.value for k in call.keywords if k.arg == "mode"] + call.args[1:2]
    return any(isinstance(m, ast.Constant) and m.value in ("w", "a") for m in modes)


def _found(path: Path) -> set[tuple[str, str]]:
    rel = path.relative_to(PACKAGE).as_posix()
    tree = ast.parse(path.read_text(), str(path))
    aliases: dict[str, str] = {}  # local name -> "laspy" / "lazrs" / "laspy.open" ...
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                root = a.name.split(".")[0]
                if root in READERS:
                    aliases[a.asname or root] = root
        elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] in READERS:
            root = node.module.split(".")[0]
            for a in node.names:
                aliases[a.asname or a.name] = f"{root}.{a.name}"
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            root = aliases[node.value.id]
            if root in READERS and node.attr in READERS[root]:
                out.add((rel, f"{root}.{node.attr}", node.lineno))
        elif isinstance(node, ast.Name) and node.id in aliases and "." in aliases[node.id]:
            root, name = aliases[node.id].split(".", 1)
            if name in READERS[root]:
                out.add((rel, aliases[node.id], node.lineno))
        elif isinstance(node, ast.Attribute) and node.attr in METHODS:
            out.add((rel, f".{node.attr}", node.lineno))
    writes = {(rel, "laspy.open", node.lineno) for node in ast.walk(tree)
              if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "open"
              and isinstance(node.func.value, ast.Name) and aliases.get(node.func.value.id) == "laspy" and _writes(node)}
    return {(m, e) for m, e, _ in out - writes}


def test_no_module_outside_io_reads_laspy_or_lazrs():
    found = set()
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.relative_to(PACKAGE).parts[0] != "io":
            found |= _found(path)
    assert found == EXPECTED


def test_the_scan_sees_the_readers_in_io():
    """The scan itself: io/ holds the reading entry points it looks for."""
    found = set()
    for path in sorted((PACKAGE / "io").rglob("*.py")):
        found |= {e for _, e in _found(path)}
    assert {"laspy.open", "lazrs.read_chunk_table", "lazrs.LasZipDecompressor", ".read_points",
            ".chunk_iterator"} <= found
