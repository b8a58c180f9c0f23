"""The Python API page (``docs/python-api.md``) holds (issue 36).

- Its examples run as written.
- Every name in its table of inspection and reference functions exists.
- No public function or method of the library is left without a caller:
  a name that no library module and no benchmark uses (tests do not count) is
  dead code unless that table lists it as public API.

Callers are found by name, as vulture does: a function counts as called when
its name appears as a name, an attribute or an identifier string anywhere in
the library or the benchmarks. That over-counts (two methods of one name cover
each other) and never under-counts.
"""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys

import pytest

from tests.conftest import ROOT

PAGE = ROOT / "docs" / "python-api.md"
LIBRARY = ("graphslam", "frontend", "loopclosure", "filters", "slamcore", "datasets")


def _listed() -> list[str]:
    """The dotted names of the page's table, in order."""
    return re.findall(r"^\| `([\w.]+)` \|", PAGE.read_text(), flags=re.M)


def _resolve(dotted: str):
    parts = dotted.split(".")
    for cut in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


def _library_files():
    return [p for d in LIBRARY if (ROOT / d).is_dir() for p in sorted((ROOT / d).rglob("*.py"))]


def _public_definitions() -> list[tuple[str, str]]:
    """``(file:line, dotted name)`` of every public function and method in the library."""
    out = []
    for path in _library_files():
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)

        def visit(node, prefix):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.ClassDef):
                    visit(child, f"{prefix}.{child.name}")
                elif isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                    if not child.name.startswith("_"):
                        out.append((f"{path.relative_to(ROOT)}:{child.lineno}", f"{prefix}.{child.name}"))
                    visit(child, f"{prefix}.{child.name}")

        visit(ast.parse(path.read_text()), module)
    return out


def _used_names() -> set[str]:
    names: set[str] = set()
    for path in _library_files() + sorted((ROOT / "benchmarks").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Name):
                names.add(node.id)
            elif isinstance(node, ast.Attribute):
                names.add(node.attr)
            elif isinstance(node, ast.alias):
                names.add(node.name.rsplit(".", 1)[-1])
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.isidentifier():
                names.add(node.value)  # getattr(obj, "name"), registries keyed by name
    return names


def test_every_listed_name_exists():
    listed = _listed()
    assert len(listed) >= 10, "the table of docs/python-api.md was not found"
    for dotted in listed:
        assert callable(_resolve(dotted)) or isinstance(_resolve(dotted), property), dotted


def test_no_public_function_without_a_caller_unless_listed():
    listed = {d.rsplit(".", 1)[-1] for d in _listed()}
    used = _used_names()
    orphans = [f"{where} {name}" for where, name in _public_definitions()
               if name.rsplit(".", 1)[-1] not in used | listed]
    assert not orphans, ("no library or benchmark caller; delete, or list in docs/python-api.md:\n"
                         + "\n".join(orphans))


def test_scan_finds_an_orphan(tmp_path, monkeypatch):
    """The scan itself can fail: a module with a function nothing calls is reported."""
    pkg = tmp_path / "slamcore"
    pkg.mkdir()
    (pkg / "orphan.py").write_text("def never_called_anywhere_xyz():\n    return 1\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert [n for _, n in _public_definitions()] == ["slamcore.orphan.never_called_anywhere_xyz"]
    (tmp_path / "benchmarks").mkdir()
    assert "never_called_anywhere_xyz" not in _used_names()


@pytest.mark.parametrize("block", range(2))
def test_examples_run(block, tmp_path):
    code = re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)[block]
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith(("ATE ", "100 poses"))
