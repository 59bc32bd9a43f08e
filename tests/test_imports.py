"""The package's import graph: no cycles, no private names across modules, kernels import no core, the
options import no stage.

Imports inside functions count: a lazy import is still a dependency. So does
``import_module(NAME)`` / ``importlib.import_module(NAME, package)`` /
``__import__(NAME)`` when NAME is known from the source: a string literal, or
an f-string of literals and ``__name__`` / ``__package__``, relative names
resolved against ``package=`` (a literal, ``__name__`` or ``__package__``).
Every other call (a name taken from a table or a variable) is listed in
``DYNAMIC`` with what it loads, so a new one is seen; the rules' modules that
``core/rules/dispatch.py`` loads by the rule table's names (``Rule.module``)
are its edges too. The graph is read from
the source (``ast``), nothing is imported.

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


#: the modules whose ``import_module`` calls take a name the source does not spell out, with what they load
DYNAMIC = {
    "cloudsieve": "the public names of its lazy table (_LAZY)",
    "cloudsieve.lazy": "a package's names at first use (lazy_names)",
    "cloudsieve.cli": "the subcommands' modules, found by listing the package",
    "cloudsieve.io": "the format modules of the formats table",
    "cloudsieve.core.warmup": "the kernel modules of each warm-up target",
    "cloudsieve.core.rules.dispatch": "each rule's module, named by the rule table (Rule.module)",
    "cloudsieve.engine.small": "the modules a small run preloads",
    "cloudsieve.engine.memory": "numpy's private core module that sets madvise hugepages",
}


def _known(node: ast.expr | None, name: str, package: str) -> str | None:
    """The text of *node* when the source spells it out: a literal, or an f-string of literals and
    ``__name__`` / ``__package__`` (None otherwise)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.Name) and node.id in ("__name__", "__package__"):
        return name if node.id == "__name__" else package
    if isinstance(node, ast.JoinedStr):
        parts = [_known(v.value if isinstance(v, ast.FormattedValue) else v, name, package) for v in node.values]
        return None if None in parts else "".join(parts)
    return None


def _loaded(call: ast.Call, name: str, package: str) -> str | None:
    """The absolute module name an ``import_module`` / ``__import__`` call loads, or None when the source does not
    say; "" when the call is none of them."""
    func = call.func
    called = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""
    if called not in ("import_module", "__import__") or not call.args:
        return ""
    target = _known(call.args[0], name, package)
    if target is None or not target.startswith("."):
        return target
    anchor = next((kw.value for kw in call.keywords if kw.arg == "package"), None)
    if anchor is None and called == "import_module" and len(call.args) > 1:
        anchor = call.args[1]
    base = _known(anchor, name, package)
    if base is None:
        return None
    level = len(target) - len(target.lstrip("."))
    for _ in range(level - 1):
        base = base.rsplit(".", 1)[0]
    rest = target.lstrip(".")
    return base + ("." + rest if rest else "")


def _table_modules() -> set[str]:
    """The modules the rule table names (``Rule(name, ..., module, ...)``, relative to cloudsieve.core.rules)."""
    tree = ast.parse((SRC / "cloudsieve" / "rule_table.py").read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Rule"]
    found = {"cloudsieve.core.rules" + c.args[5].value for c in calls}
    assert len(found) == len(calls) == 5, found
    return found


def _graph() -> tuple[dict[str, set[str]], list[tuple[str, str, str]]]:
    """Each module's imported modules (with the packages a dotted import runs), and the private names imported
    across modules: (importer, module, name)."""
    edges, private, _ = _read()
    return edges, private


def _read() -> tuple[dict[str, set[str]], list[tuple[str, str, str]], set[str]]:
    """:func:`_graph`'s edges and private names, and the modules with an ``import_module`` call whose name the
    source does not spell out."""
    mods = _modules()
    edges: dict[str, set[str]] = {m: set() for m in mods}
    private = []
    dynamic = set()
    for m, path in mods.items():
        package = m if path.name == "__init__.py" else m.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call):
                target = _loaded(node, m, package)
                if target is None:
                    dynamic.add(m)
                elif target in mods:
                    edges[m].add(target)
            elif isinstance(node, ast.ImportFrom):
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
    edges["cloudsieve.core.rules.dispatch"] |= _table_modules()
    for m in edges:  # importing a.b.c runs a and a.b first
        for t in list(edges[m]):
            parts = t.split(".")
            for i in range(1, len(parts)):
                anc = ".".join(parts[:i])
                if anc in mods and anc != m and not m.startswith(anc + "."):
                    edges[m].add(anc)
    return edges, private, dynamic


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


def test_every_import_module_call_is_followed_or_listed():
    *_, dynamic = _read()
    assert dynamic == set(DYNAMIC)


def test_the_options_import_no_stage():
    """params and params_spec reach no module of core, engine, store, io or evaluate, directly or not: the rule
    table they read is a leaf."""
    edges, _ = _graph()
    stages = tuple(f"cloudsieve.{p}" for p in ("core", "engine", "store", "io", "evaluate"))
    for start in ("cloudsieve.params", "cloudsieve.params_spec"):
        seen, todo = set(), [start]
        while todo:
            for t in edges[todo.pop()] - seen:
                seen.add(t)
                todo.append(t)
        assert sorted(t for t in seen if any(t == s or t.startswith(s + ".") for s in stages)) == [], start


def test_import_module_calls_are_edges():
    """The calls the graph follows, on small sources: literal, f-string, relative with package=."""
    cases = {
        'import_module("cloudsieve.errors")': "cloudsieve.errors",
        'importlib.import_module(".dispatch", __name__)': "cloudsieve.core.rules.dispatch",
        'import_module("..entropy", package=__package__)': "cloudsieve.core.entropy",
        'importlib.import_module(f"{__package__}.threshold")': "cloudsieve.core.rules.threshold",
        'import_module(f".{name}", __name__)': None,
        'import_module(NAME)': None,
        '__import__("cloudsieve.params")': "cloudsieve.params",
        'len("x")': "",
    }
    got = {src: _loaded(ast.parse(src).body[0].value, "cloudsieve.core.rules", "cloudsieve.core.rules")
           for src in cases}
    assert got == cases
