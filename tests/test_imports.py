"""The package's import graph: no cycles, no private names across modules, kernels import no core.

Imports inside functions count: a lazy import is still a dependency. The
graph is read from the source (``ast``), nothing is imported.

``EXPECTED`` lists known exceptions, each with its reason (none today); an
entry that no longer occurs fails the test too, so the list stays exact.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: known exceptions (none): a finding listed here must occur, or the test fails
EXPECTED = {
    "cycle": set(),
    "private": set(),
    "upward": set(),
}


def _modules() -> dict[str, Path]:
    out = {}
    for path in (SRC / "cloudsieve").rglob("*.py"):
        name = ".".join(path.relative_to(SRC).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = path
    return out


def _graph() -> tuple[dict[str, set[str]], list[tuple[str, str, str]]]:
    """Each module's imported modules (with the packages a dotted import runs), and the private names imported
    across modules: (importer, module, name)."""
    mods = _modules()
    edges: dict[str, set[str]] = {m: set() for m in mods}
    private = []
    for m, path in mods.items():
        package = m if path.name == "__init__.py" else m.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package
                    for _ in range(node.level - 1):
                        base = base.rsplit(".", 1)[0]
                    target = base + ("." + node.module if node.module else "")
                else:
                    target = node.module or ""
                if not target.startswith("cloudsieve"):
                    continue
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    if sub in mods:
                        edges[m].add(sub)
                    elif target in mods:
                        edges[m].add(target)
                        name = alias.name
                        if name.startswith("_") and not (name.startswith("__") and name.endswith("__")):
                            private.append((m, target, name))  # dunders (__all__, __version__) are public
            elif isinstance(node, ast.Import):
                edges[m].update(a.name for a in node.names if a.name in mods)
    for m in edges:  # importing a.b.c runs a and a.b first
        for t in list(edges[m]):
            parts = t.split(".")
            for i in range(1, len(parts)):
                anc = ".".join(parts[:i])
                if anc in mods and anc != m and not m.startswith(anc + "."):
                    edges[m].add(anc)
    return edges, private


def _cycles(edges: dict[str, set[str]]) -> set[tuple[str, ...]]:
    """The strongly connected components of more than one module (Tarjan), each as a sorted tuple."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: set[tuple[str, ...]] = set()

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                out.add(tuple(sorted(scc)))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    edges, _ = _graph()
    assert _cycles(edges) == EXPECTED["cycle"]


def test_no_private_names_imported_across_modules():
    _, private = _graph()
    assert {(m, f"{t}.{n}") for m, t, n in private} == EXPECTED["private"]


def test_the_kernels_import_nothing_of_core_outside_them():
    edges, _ = _graph()
    kernels = "cloudsieve.core.kernels"
    upward = {(m, t) for m, ts in edges.items() if m == kernels or m.startswith(kernels + ".")
              for t in ts if t.startswith("cloudsieve.core") and t != "cloudsieve.core"
              and not (t == kernels or t.startswith(kernels + "."))}
    assert upward == EXPECTED["upward"]
