"""The user documentation stays true to the tree: README.md, docs/ and the modules they name.

- docs/architecture.md names modules by their path under ``src/cloudsieve/``
  in backticks (```core/knn.py```); every such path must exist, and every
  module of the package must be named there. Paths from the repository root
  (``tests/...``, ``benchmarks/...``, ``src/...``) are files, not modules.
- Dotted names ``cloudsieve.x.y`` in README.md and docs/*.md must resolve to
  a module or an attribute of one.
- README.md stays short (at most 400 lines).
- README.md, docs/ and the docstrings and comments of src/ state what the code
  is and does, not when or how it came to be: no journal words (`JOURNAL`:
  "session", "this VM", "today", "that day", "this hour", "a slower day",
  "an earlier run", "tried", "previously", "the code before", "this machine"
  and the like). A result names its benchmark and the load average, and the
  machine as "2 cores, 24 GiB" or "the benchmark machine". Words that also
  describe the present ("no longer", "used to", "now") are not in the list.
"""

from __future__ import annotations

import ast
import importlib
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "cloudsieve"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
README = ROOT / "README.md"

_MODULE_PATH = re.compile(r"`([A-Za-z_][\w]*(?:/[A-Za-z_][\w]*)*\.py)`")
_NOT_MODULES = ("tests/", "benchmarks/", "src/", "pipelines/")
_DOTTED = re.compile(r"(?<![\w./-])cloudsieve(?:\.[A-Za-z_]\w*)+")
JOURNAL = re.compile("|".join([
    r"session", r"this vm", r"\btoday\b", r"\byesterday\b",
    r"\b(?:this|that|the same|another|a later|an earlier) (?:day|hour|half hour|afternoon|morning|week)\b",
    r"\bsame minutes\b",
    r"\b(?:slow|slower|fast|faster|quiet|quieter) (?:days?|phases?|minutes?|hours?)\b",
    r"\b(?:an|a|the) (?:earlier|later) runs?\b",
    r"\btried\b", r"\bwe (?:measured|found|saw|kept)\b", r"\bpreviously\b",
    r"\bthe code before\b", r"\bthese changes\b",
    r"\bthis machine\b", r"\btest machine\b",
]), re.IGNORECASE)


def named_modules(text: str) -> set[str]:
    """The module paths (relative to src/cloudsieve/) named in *text*."""
    return {m for m in _MODULE_PATH.findall(text) if not m.startswith(_NOT_MODULES)}


def package_modules() -> set[str]:
    return {p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py")}


def resolves(dotted: str) -> bool:
    """True when *dotted* is a module, or an attribute chain of the longest importable module prefix."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


def test_architecture_names_only_existing_modules():
    named = named_modules(ARCHITECTURE.read_text(encoding="utf-8"))
    missing = sorted(m for m in named if not (PACKAGE / m).is_file())
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"


def test_architecture_names_every_module():
    named = named_modules(ARCHITECTURE.read_text(encoding="utf-8"))
    unnamed = sorted(package_modules() - named)
    assert not unnamed, f"modules under src/cloudsieve/ that docs/architecture.md does not name: {unnamed}"


@pytest.mark.parametrize("doc", [README, *sorted((ROOT / "docs").glob("*.md"))], ids=lambda p: p.name)
def test_dotted_names_resolve(doc):
    text = doc.read_text(encoding="utf-8")
    bad = sorted({name.rstrip(".") for name in _DOTTED.findall(text) if not resolves(name.rstrip("."))})
    assert not bad, f"{doc.name} names {bad}, which are neither modules nor their attributes"


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= 400, f"README.md has {lines} lines, at most 400"


def prose(path: Path) -> list[tuple[int, str]]:
    """The lines of *path* a reader takes for prose: all of a Markdown file; a Python file's comments and docstrings."""
    text = path.read_text(encoding="utf-8")
    if path.suffix != ".py":
        return list(enumerate(text.splitlines(), 1))
    lines = [(t.start[0], t.string) for t in tokenize.generate_tokens(io.StringIO(text).readline)
             if t.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                lines += [(first.lineno + i, line) for i, line in enumerate(first.value.value.splitlines())]
    return lines


def _documents():
    yield README
    yield from sorted((ROOT / "docs").rglob("*.md"))
    yield from sorted(PACKAGE.rglob("*.py"))


def test_no_journal_words():
    found = []
    for path in _documents():
        for number, line in prose(path):
            if JOURNAL.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_checks_see_a_bad_name():
    assert named_modules("`core/knn.py`, `tests/test_docs.py`, `cloudsieve/prune.py`") == {"core/knn.py",
                                                                                          "cloudsieve/prune.py"}
    assert resolves("cloudsieve.core.knn") and resolves("cloudsieve.simplify")
    assert not resolves("cloudsieve.prune.REFINE_LABEL_TOL")
    for journal in ("in the 2nd Session", "on This VM", "Today", "on a slower day", "in that hour",
                    "an earlier run gave", "Tried and not kept", "previously", "the code before (c450261)",
                    "on this machine", "in the same minutes", "in a slow phase"):
        assert JOURNAL.search(journal), journal
    for fine in ("the benchmark machine", "runs of the default rule", "retried requests", "no longer COPC",
                 "the GPS day"):
        assert not JOURNAL.search(fine), fine


def test_prose_is_comments_and_docstrings(tmp_path):
    module = tmp_path / "m.py"
    module.write_text('''"""Module doc."""\nx = "today"  # a comment\ndef f():\n    """Doc\n    line two."""\n''')
    assert sorted(prose(module)) == [(1, "Module doc."), (2, "# a comment"), (4, "Doc"), (5, "    line two.")]
