"""No function outside the kernels (``core/kernels/``) and the public API takes more than ten parameters.

Options travel as one object (DESIGN.md, "One pipeline for every size"):
validated once at the entry and passed whole; kernels take small structs.
A parameter is a named one (``self`` and ``cls`` aside), ``*args`` or
``**kwargs``. The public API is what ``cloudsieve.__all__`` names: its
functions and its classes' public methods and ``__init__``. The signatures are read from the source
(``ast``); only the public names are imported, to find where they live.

:data:`OVER` lists the functions that still take more (the work left); the
list must stay exact, so it can only shrink.
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import cloudsieve

PACKAGE = Path(cloudsieve.__file__).resolve().parent
LIMIT = 10

#: functions outside the kernels and the public API that take more than LIMIT parameters, with their count
OVER: dict[str, int] = {}


def _count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = node.args
    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def _functions() -> dict[str, int]:
    """Every function of the package outside core/kernels/, as ``path:Qual.name``, with its parameter count."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel.startswith("core/kernels/"):
            continue

        def visit(node: ast.AST, prefix: str) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    name = f"{prefix}{child.name}"
                    if not isinstance(child, ast.ClassDef):
                        out[f"{rel}:{name}"] = _count(child)
                    visit(child, name + ".")
                else:
                    visit(child, prefix)

        visit(ast.parse(path.read_text(), str(path)), "")
    return out


def _public() -> set[str]:
    """The functions of the public API (``cloudsieve.__all__``) and its classes' methods, as ``path:Qual.name``."""
    found = set()
    for name in cloudsieve.__all__:
        obj = getattr(cloudsieve, name)
        members = [obj] if inspect.isfunction(obj) else [
            m for n, m in inspect.getmembers(obj, inspect.isfunction) if n == "__init__" or not n.startswith("_")
        ] if inspect.isclass(obj) else []
        for f in members:
            f = inspect.unwrap(f)
            path = Path(inspect.getsourcefile(f)).resolve()
            if path.is_relative_to(PACKAGE):
                found.add(f"{path.relative_to(PACKAGE).as_posix()}:{f.__qualname__}")
    return found


def test_no_function_outside_the_kernels_and_the_api_takes_more_than_ten_parameters():
    public = _public()
    over = {name: n for name, n in _functions().items() if n > LIMIT and name not in public}
    assert over == OVER


def test_the_public_api_is_found():
    public = _public()
    assert {"engine/simplify.py:simplify", "core/simplify.py:simplify_points", "core/rules/dispatch.py:prune",
            "evaluate/compare.py:compare", "core/cluster.py:CentroidClustering.fit"} <= public
    assert "core/kmeans.py:KMeans._iterate" not in public
