"""The layering rules of ARCHITECTURE.md, checked by reading every module's imports.

:func:`check_tree` parses each ``.py`` file of the library packages with
:mod:`ast` (imports inside functions included, nothing is imported) and
returns one message per broken rule:

- **rank**: a module may import only from its own layer or a lower one
  (:data:`RANKS`); siblings of one rank that are different top-level packages
  (``frontend`` and ``filters``), or listed in :data:`APART` (``graphslam.pipelines``
  and ``graphslam.visualisation``), do not import each other;
- **cycle**: no import cycle between modules;
- **tool**: gtsam, rerun, matplotlib and argparse only where :data:`TOOLS`
  allows them;
- **private**: no ``_name`` imported from another of our modules (``from m
  import _f``, or ``m._f`` through an imported module).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

#: Library packages checked (tests and benchmarks are scripts around them).
PACKAGES = ("slamcore", "frontend", "filters", "loopclosure", "graphslam")

#: Packages of one rank inside ``graphslam`` that do not import each other either (the
#: runs compute, the drawing draws what the CLI hands it).
APART = ({"graphslam.pipelines", "graphslam.visualisation"},)

#: Layer of each package (the longest matching prefix wins); lower may not import higher.
RANKS: dict[str, int] = {
    "slamcore": 0,
    "frontend": 1,
    "filters": 1,
    "loopclosure": 2,
    "graphslam.sources": 3,
    "graphslam.backends": 3,
    "graphslam.evaluation": 3,
    "graphslam.outputs": 3,
    "graphslam.maps": 3,
    "graphslam.registry": 4,
    "graphslam.backend_table": 4,
    "graphslam.pipelines": 5,
    "graphslam.visualisation": 5,
    "graphslam.cli": 7,
    "graphslam": 8,
}

#: Third-party modules allowed only under these prefixes of ours.
TOOLS: dict[str, tuple[str, ...]] = {
    "gtsam": ("graphslam.backends", "graphslam.sources"),
    "rerun": ("graphslam.visualisation.recording", "graphslam.visualisation.planar",
              "graphslam.visualisation.spatial", "graphslam.visualisation.layout"),
    "matplotlib": ("graphslam.visualisation.plots",),
    "argparse": ("graphslam.cli",),
}


@dataclass(frozen=True)
class Import:
    module: str  # importing module
    target: str  # imported module (ours or third party), resolved
    names: tuple[str, ...]  # names taken by a from-import
    line: int


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def rank_of(module: str) -> tuple[str, int] | None:
    best = max((p for p in RANKS if _under(module, p)), key=len, default=None)
    return None if best is None else (best, RANKS[best])


def module_files(root: Path) -> dict[str, Path]:
    """``{dotted module name: file}`` of every library module under ``root``."""
    out = {}
    for pkg in PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")) if (root / pkg).is_dir() else []:
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _resolve(module: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    base = base if is_pkg else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(module: str, path: Path, known: set[str]) -> tuple[list[Import], list[tuple[str, str, int]]]:
    """Imports of one module, and attribute uses ``(alias target, attr, line)``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    found: list[Import] = []
    aliases: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                found.append(Import(module, a.name, (), node.lineno))
                aliases[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            src = _resolve(module, is_pkg, node)
            plain = []
            for a in node.names:
                sub = f"{src}.{a.name}"
                if sub in known:  # `from pkg import module`
                    found.append(Import(module, sub, (), node.lineno))
                    aliases[a.asname or a.name] = sub
                else:
                    plain.append(a.name)
            if plain or not node.names:
                found.append(Import(module, src, tuple(plain), node.lineno))
    attrs = [(aliases[n.value.id], n.attr, n.lineno) for n in ast.walk(tree)
             if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
             and n.value.id in aliases]
    return found, attrs


def _ours(target: str) -> bool:
    return any(_under(target, p) for p in PACKAGES)


def _rule_violations(imp: Import, known: set[str]) -> list[str]:
    where = f"{imp.module} (line {imp.line})"
    out = []
    top = imp.target.split(".")[0]
    if top in TOOLS and not any(_under(imp.module, p) for p in TOOLS[top]):
        out.append(f"tool: {where} imports {top}, allowed only in {', '.join(TOOLS[top])}")
    if not _ours(imp.target):
        return out
    mine, theirs = rank_of(imp.module), rank_of(imp.target)
    if mine and theirs and not _under(imp.module, imp.target):  # a package's own __init__ is fine
        if theirs[1] > mine[1]:
            out.append(f"rank: {where} imports {imp.target} from a higher layer "
                       f"({theirs[0]} = {theirs[1]} > {mine[0]} = {mine[1]})")
        elif theirs[1] == mine[1] and (imp.module.split(".")[0] != imp.target.split(".")[0]
                                       or {mine[0], theirs[0]} in APART):
            out.append(f"rank: {where} imports its sibling package {imp.target}")
    for name in imp.names:
        if name.startswith("_") and not name.startswith("__"):
            out.append(f"private: {where} imports {name} from {imp.target}")
    return out


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def check_tree(root: Path) -> list[str]:
    """Every broken rule under ``root`` (a checkout holding the library packages)."""
    files = module_files(root)
    known = set(files)
    problems: list[str] = []
    edges: dict[str, set[str]] = {}
    for module, path in files.items():
        found, attrs = imports_of(module, path, known)
        for imp in found:
            problems += _rule_violations(imp, known)
            target = imp.target if imp.target in known else None
            if target and target != module and not _under(module, target):
                edges.setdefault(module, set()).add(target)
        for target, attr, line in attrs:
            if (_ours(target) and target != module and attr.startswith("_")
                    and not attr.startswith("__")):
                problems.append(f"private: {module} (line {line}) uses {target}.{attr}")
    problems += [f"cycle: {' <-> '.join(c)}" for c in _cycles(edges)]
    return problems
