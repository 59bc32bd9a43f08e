"""The user documentation stays true to the tree: README.md, docs/ and the modules they name.

- docs/architecture.md names modules by their path under ``src/cloudsieve/``
  in backticks (```core/knn.py```); every such path must exist, and every
  module of the package must be named there. Paths from the repository root
  (``tests/...``, ``benchmarks/...``, ``src/...``) are files, not modules.
- Dotted names ``cloudsieve.x.y`` in README.md and docs/*.md must resolve to
  a module or an attribute of one.
- README.md stays short (at most 400 lines).
- No file in README.md, docs/ or src/ speaks of a "session" or "this VM".
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "cloudsieve"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
README = ROOT / "README.md"

_MODULE_PATH = re.compile(r"`([A-Za-z_][\w]*(?:/[A-Za-z_][\w]*)*\.py)`")
_NOT_MODULES = ("tests/", "benchmarks/", "src/", "pipelines/")
_DOTTED = re.compile(r"(?<![\w./-])cloudsieve(?:\.[A-Za-z_]\w*)+")
_BANNED = re.compile(r"session|this vm", re.IGNORECASE)


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


def _documents():
    yield README
    yield from sorted((ROOT / "docs").rglob("*.md"))
    yield from sorted(PACKAGE.rglob("*.py"))


def test_no_words_about_how_the_work_was_organised():
    found = []
    for path in _documents():
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if _BANNED.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_checks_see_a_bad_name():
    assert named_modules("`core/knn.py`, `tests/test_docs.py`, `cloudsieve/prune.py`") == {"core/knn.py",
                                                                                          "cloudsieve/prune.py"}
    assert resolves("cloudsieve.core.knn") and resolves("cloudsieve.simplify")
    assert not resolves("cloudsieve.prune.REFINE_LABEL_TOL")
    assert _BANNED.search("in the 2nd Session") and _BANNED.search("on This VM")
