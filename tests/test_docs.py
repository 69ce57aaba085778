"""The documentation points at what exists: every module, attribute, file and test it names.

Read from ``README.md``, ``docs/*.md`` and the docstrings and comments of ``src/hinfnn``:

* dotted names ``hinfnn.xxx.yyy``: the longest prefix that is a module must be found
  (:func:`importlib.util.find_spec`) and the rest must be attributes of it (a dataclass field
  counts as an attribute of its class);
* backticked paths ``src/hinfnn/….py`` (and ``hinfnn/….py``, ``tests/….py``, ``benchmarks/….py``)
  must be files of the repository, a backticked ``tests/test_x.py::test_name`` a test of that
  file, and every ``docs/….md`` a page;
* ``docs/architecture.md`` lists every module under ``src/hinfnn`` (its module map).
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import importlib.util
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src" / "hinfnn"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: ``hinfnn.a.b``: not inside a path or a longer identifier (``src/hinfnn/…``, ``my-hinfnn.x``).
DOTTED = re.compile(r"(?<![\w/.\-])hinfnn(?:\.[A-Za-z_]\w*)+")
#: A backticked repository path of a Python file, with an optional ``::test_name``.
PATH = re.compile(r"`((?:src/)?hinfnn/[\w/.\-]*\.py|tests/[\w/.\-]*\.py|benchmarks/[\w/.\-]*\.py)(?:::(\w+))?`")
#: A page of the documentation, backticked or not.
PAGE = re.compile(r"(?<![\w/.\-])docs/[\w\-]+\.md")


def _source_text(path: Path) -> str:
    """The docstrings and comments of one module, one per line (the code itself left out)."""
    text = path.read_text(encoding="utf-8")
    parts = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                parts.append(doc)
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.COMMENT:
            parts.append(tok.string)
    return "\n".join(parts)


def _texts() -> dict[str, str]:
    out = {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8") for p in DOCS}
    for p in sorted(SRC.rglob("*.py")):
        out[str(p.relative_to(ROOT))] = _source_text(p)
    return out


def _find_spec(name: str):
    try:
        return importlib.util.find_spec(name)
    except (ImportError, AttributeError, ValueError):  # a parent that is a module, not a package
        return None


def _has(obj, attr: str) -> bool:
    if hasattr(obj, attr):
        return True
    if isinstance(obj, type):  # a field without a default is no class attribute
        for klass in obj.__mro__:
            if attr in getattr(klass, "__annotations__", {}):
                return True
            if dataclasses.is_dataclass(klass) and attr in {f.name for f in dataclasses.fields(klass)}:
                return True
    return False


def resolve(name: str) -> str | None:
    """Why the dotted name ``name`` does not resolve (None: it does)."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        module = ".".join(parts[:i])
        if _find_spec(module) is not None:
            break
    else:
        return f"no module {parts[0]!r}"
    rest = parts[i:]
    if not rest:
        return None
    try:
        obj = importlib.import_module(module)
    except Exception as e:  # noqa: BLE001 - a module that fails to import is the finding
        return f"module {module} does not import: {type(e).__name__}: {e}"
    for j, attr in enumerate(rest):
        if not _has(obj, attr):
            where = ".".join([module, *rest[:j]])
            return f"{where} has no attribute {attr!r} (no module {where}.{attr} either)"
        obj = getattr(obj, attr, None)
        if obj is None:  # a field known only by its annotation: nothing further to look up
            return None
    return None


def _test_names(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}


def check_paths(text: str) -> list[str]:
    """The backticked file paths (and ``file::test``) and the documentation pages of ``text``
    that do not exist."""
    bad = [f"{page}: no such page" for page in sorted(set(PAGE.findall(text))) if not (ROOT / page).is_file()]
    for m in PATH.finditer(text):
        rel, test = m.group(1), m.group(2)
        path = ROOT / ("src/" + rel if rel.startswith("hinfnn/") else rel)
        if not path.is_file():
            bad.append(f"`{m.group(0).strip('`')}`: no file {rel}")
        elif test and test not in _test_names(path):
            bad.append(f"`{m.group(0).strip('`')}`: {rel} has no {test}")
    return bad


def test_every_module_reference_in_the_docs_and_docstrings_resolves():
    found, bad = 0, []
    cache: dict[str, str | None] = {}
    for where, text in _texts().items():
        for name in sorted(set(DOTTED.findall(text))):
            found += 1
            if name not in cache:
                cache[name] = resolve(name)
            if cache[name]:
                bad.append(f"{where}: {name}: {cache[name]}")
    assert found > 100, f"only {found} references found: is the pattern right?"
    assert not bad, "references that do not resolve:\n" + "\n".join(bad)


def test_every_file_path_in_the_docs_and_docstrings_exists():
    found, bad = 0, []
    for where, text in _texts().items():
        found += len(PATH.findall(text)) + len(PAGE.findall(text))
        bad += [f"{where}: {b}" for b in check_paths(text)]
    assert found > 20, f"only {found} paths found: is the pattern right?"
    assert not bad, "paths that do not exist:\n" + "\n".join(bad)


def test_the_architecture_lists_every_module():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    assert "\n## Module map\n" in text, "docs/architecture.md has no section '## Module map'"
    section = text.split("\n## Module map\n", 1)[1].split("\n## ", 1)[0]
    listed = {p for p in re.findall(r"`([\w/]+\.py)`", section) if not p.startswith("tests/")}
    modules = {str(p.relative_to(SRC)) for p in SRC.rglob("*.py")}
    assert not modules - listed, f"modules missing from docs/architecture.md's module map: {sorted(modules - listed)}"
    assert not listed - modules, f"docs/architecture.md lists modules that do not exist: {sorted(listed - modules)}"


@pytest.mark.parametrize("name, problem", [
    ("hinfnn.sim.simulate", None),
    ("hinfnn._loop.LoopOptions.sincos", None),
    ("hinfnn.sim.Trajectory", None),
    ("hinfnn.simulate", None),  # a lazy name of the package
    ("hinfnn.sim.programs", "hinfnn.sim has no attribute 'programs'"),
    ("hinfnn._devices", "hinfnn has no attribute '_devices'"),
    ("hinfnn._loop.NoSuchOption", "hinfnn._loop has no attribute 'NoSuchOption'"),
])
def test_the_checks_can_fail(name, problem):
    """The resolver finds what exists and names what does not (the stale references of issue 53)."""
    got = resolve(name)
    assert (got is None) if problem is None else (got is not None and problem in got), got
    assert check_paths("`src/hinfnn/_loop.py` and `tests/test_docs.py::test_the_checks_can_fail`") == []
    assert check_paths("`src/hinfnn/_devices.py`") == ["`src/hinfnn/_devices.py`: no file src/hinfnn/_devices.py"]
    assert check_paths("see docs/performance.md and docs/nowhere.md") == ["docs/nowhere.md: no such page"]
    assert check_paths("`tests/test_docs.py::test_nothing`") == ["`tests/test_docs.py::test_nothing`: "
                                                                 "tests/test_docs.py has no test_nothing"]
    assert DOTTED.findall("see src/hinfnn/sim.py, hinfnn.sim.simulate(...) and hinfnn.") == ["hinfnn.sim.simulate"]
