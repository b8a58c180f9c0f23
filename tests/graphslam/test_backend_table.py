"""The one table of back ends (graphslam.backend_table): every row's implementations
exist and agree with what the row claims, and no layer compares back-end names
instead of asking the table."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from graphslam import registry
from slamcore.errors import ConfigError
from graphslam.backend_table import TABLE, VISUAL_COMPARE_BACKENDS, Implementation, load
from tests.conftest import ROOT

#: Where back-end names may appear as compared strings: the table itself, and the
#: pose-graph solvers' own dispatch (they are the implementation of those names).
ALLOWED = {ROOT / "graphslam" / "backend_table.py"} | set(
    (ROOT / "graphslam" / "backends" / "posegraph").glob("*.py"))
NAMES = {d.name for d in TABLE}


def _implementations():
    for row in TABLE:
        for kind in ("landmarks", "images"):
            impl = getattr(row, kind)
            if impl is not None:
                yield pytest.param(row, impl, id=f"{row.name}-{kind}")


@pytest.mark.parametrize("row, impl", list(_implementations()))
def test_every_implementation_imports_and_agrees_with_its_row(row, impl: Implementation):
    backend, config = load(impl.backend), load(impl.config)
    assert isinstance(backend, type) and dataclasses.is_dataclass(config)
    assert config.SECTION in registry.CONFIG_SECTIONS
    fields = {f.name for f in dataclasses.fields(config)}
    assert set(impl.fixed) <= fields
    if row.polish:  # --no-polish hands polish = False
        assert "polish" in fields
    if impl.seeded:
        assert "seed" in fields
    if impl.localiser is not None:
        assert isinstance(load(impl.localiser), type)


def test_names_are_unique_and_every_row_runs_on_something():
    assert len(NAMES) == len(TABLE)
    for row in TABLE:
        assert row.landmarks is not None or row.images is not None or row.pose_graph, row
        assert row.streams == (row.landmarks is not None or row.images is not None), row
    assert {backend for backend, _ in VISUAL_COMPARE_BACKENDS.values()} == set(
        registry.VISUAL_BACKENDS)
    assert sum(row.reference for row in TABLE) == 1


def test_an_unknown_or_misplaced_name_is_one_line():
    with pytest.raises(ConfigError, match="unknown back end 'nope'"):
        registry.make_backend("nope")
    with pytest.raises(ConfigError, match="does not run on 2-D data"):
        registry.make_backend("batch")
    with pytest.raises(ConfigError, match="does not run on image sequences"):
        registry.visual_backend_config("fastslam1")


def _compared_names(path: Path) -> list[tuple[int, str]]:
    """Back-end names in ``==``/``!=``/``in`` comparisons and ``startswith`` calls."""
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        strings: list[ast.AST] = []
        if isinstance(node, ast.Compare):
            for op, right in zip(node.ops, node.comparators):
                if isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn)):
                    strings += [node.left, right]
                    if isinstance(right, (ast.Tuple, ast.List, ast.Set)):
                        strings += right.elts
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr == "startswith"):
            strings += node.args
        found += [(node.lineno, s.value) for s in strings
                  if isinstance(s, ast.Constant) and s.value in NAMES]
    return found


def test_no_layer_compares_back_end_names():
    """Issue 36: a new back end is a row of the table, not an edit of scattered checks.
    Names that are also other settings' values (``auto``) are checked too: a setting
    compared with ``"auto"`` is flagged only where the module is about back ends."""
    offenders = []
    for path in sorted((ROOT / "graphslam").rglob("*.py")):
        if path in ALLOWED:
            continue
        for line, name in _compared_names(path):
            text = path.read_text().splitlines()[line - 1]
            if name == "auto" and "backend" not in text:
                continue  # an "auto" mode of some other setting
            offenders.append(f"{path.relative_to(ROOT)}:{line}: {name!r}")
    assert not offenders, "\n".join(offenders)


@pytest.mark.parametrize("name", registry.WHOLE_GRAPH_BACKENDS)
def test_every_whole_graph_solver_takes_a_builtin_graph(name):
    """``--backend auto`` on w10000 was refused while ``batch`` solved it: the rule is
    the row's (a whole-graph solver), not one name's."""
    assert registry.is_pose_graph_run("w10000", name)
    assert not registry.is_pose_graph_run("w10000", "isam2")  # streamed by default


def test_a_setting_the_back_end_name_fixes_is_not_overridden_silently(tmp_path):
    """``[fastslam] version = 1`` under fastslam2 ran FastSLAM 2.0 with nothing said."""
    from graphslam import registry
    from slamcore.errors import ConfigError

    cfg = tmp_path / "c.toml"
    cfg.write_text("[fastslam]\nn_particles = 5\nversion = 1\n")
    with pytest.raises(ConfigError, match=r"c.toml:3: \[fastslam\] version = 1 contradicts the back end fastslam2"):
        registry.make_backend("fastslam2", config=cfg)
    with pytest.raises(ConfigError, match="version = 2 contradicts the back end fastslam1"):
        registry.make_backend("fastslam1", overrides={"version": 2})
    assert registry.make_backend("fastslam1", config=cfg).config.version == 1  # it agrees
    cfg.write_text("[fastslam]\nversion = 2\n")
    assert registry.make_backend("fastslam2", config=cfg).config.version == 2
