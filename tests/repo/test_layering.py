"""The layering rules (ARCHITECTURE.md) hold on the tree, and the checker catches breaks.

On the tree before the layout move (commit 48ed6b1) the checker reports 65
problems (frontend, filters and loopclosure importing graphslam, gtsam outside
the back ends, argparse in library modules, a private import, the
cli <-> visual_run cycle): ``python -c "from tests.layering import check_tree;
print(*check_tree(Path('OLD_CHECKOUT')), sep='\\n')"``.
"""

from __future__ import annotations

import ast
import io
import textwrap
import tokenize
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.layering import PACKAGES, check_tree, module_files


#: Size limits, in logical lines (statements: what ``tokenize`` ends with NEWLINE), so
#: the formatter's layout (one argument a line in a long call) never moves them. The
#: style guide's "a module over about 500 lines or a function over 60 is worth a look"
#: is a smell detector; the test fails only past 500 and 80 (the longest functions,
#: the run assemblies, hold 61-64 statements). The FPGA pixel-rate kernel is one long
#: loop on purpose (it mirrors the hardware pipeline stage by stage).
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
LONG_FUNCTION_ALLOWED = {("frontend.fpga_stream", "FpgaHarrisStream._stream")}


def test_the_tree_keeps_its_layers():
    assert check_tree(ROOT) == []


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir(exist_ok=True)
        (tmp_path / pkg / "__init__.py").write_text("")
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        for parent in path.relative_to(tmp_path).parents:
            if str(parent) != ".":
                init = tmp_path / parent / "__init__.py"
                if not init.exists():
                    init.write_text("")
        path.write_text(textwrap.dedent(text))
    return tmp_path


@pytest.mark.parametrize("files, expected", [
    ({"frontend/bad.py": "from graphslam.cli.main import main\n",
      "graphslam/cli/main.py": "def main(): pass\n"}, "rank: frontend.bad"),
    ({"slamcore/bad.py": "def f():\n    from frontend import harris\n",
      "frontend/harris.py": ""}, "rank: slamcore.bad"),
    ({"filters/bad.py": "from frontend.orb import OrbDetector\n",
      "frontend/orb.py": "class OrbDetector: pass\n"}, "rank: filters.bad (line 1) imports its sibling"),
    ({"graphslam/visualisation/v.py": "from graphslam.pipelines.p import x\n",
      "graphslam/pipelines/p.py": "x = 1\n"}, "rank: graphslam.visualisation.v (line 1) imports its sibling"),
    ({"graphslam/pipelines/p.py": "from graphslam.visualisation.v import x\n",
      "graphslam/visualisation/v.py": "x = 1\n"}, "rank: graphslam.pipelines.p (line 1) imports its sibling"),
    ({"frontend/a.py": "from frontend import b\n",
      "frontend/b.py": "from frontend.a import x\nx = 1\n"}, "cycle: frontend.a <-> frontend.b"),
    ({"frontend/a.py": "from frontend.b import _hidden\n",
      "frontend/b.py": "def _hidden(): pass\n"}, "private: frontend.a"),
    ({"frontend/a.py": "from frontend import b\nb._hidden()\n",
      "frontend/b.py": "def _hidden(): pass\n"}, "private: frontend.a (line 2) uses frontend.b._hidden"),
    ({"filters/ekf.py": "import gtsam\n"}, "tool: filters.ekf"),
    ({"graphslam/pipelines/p.py": "import rerun as rr\n"}, "tool: graphslam.pipelines.p"),
    ({"graphslam/evaluation/e.py": "import matplotlib.pyplot\n"}, "tool: graphslam.evaluation.e"),
    ({"graphslam/pipelines/p.py": "import argparse\n"}, "tool: graphslam.pipelines.p"),
])
def test_the_checker_catches_a_deliberately_wrong_module(tmp_path, files, expected):
    problems = check_tree(_tree(tmp_path, files))
    assert any(p.startswith(expected) for p in problems), problems


def test_a_clean_temporary_tree_passes(tmp_path):
    files = {"frontend/a.py": "from slamcore.errors import InputError\n",
             "slamcore/errors.py": "class InputError(Exception): pass\n",
             "graphslam/cli/main.py": "import argparse\nfrom frontend import a\n"}
    assert check_tree(_tree(tmp_path, files)) == []


def _logical_line_ends(text: str) -> list[int]:
    """The physical line on which each logical line (statement) of ``text`` ends."""
    tokens = tokenize.generate_tokens(io.StringIO(text).readline)
    return [tok.start[0] for tok in tokens if tok.type == tokenize.NEWLINE]


def _functions(tree: ast.AST, ends: list[int], prefix: str = ""):
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = sum(node.lineno <= end <= node.end_lineno for end in ends)
            yield f"{prefix}{node.name}", length
            yield from _functions(node, ends, f"{prefix}{node.name}.")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, ends, f"{prefix}{node.name}.")


def test_modules_and_functions_stay_small():
    too_long = []
    for module, path in module_files(ROOT).items():
        text = path.read_text(encoding="utf-8")
        ends = _logical_line_ends(text)
        if len(ends) > MAX_MODULE_LINES:
            too_long.append(f"{module}: {len(ends)} statements")
        for name, length in _functions(ast.parse(text), ends):
            if length > MAX_FUNCTION_LINES and (module, name) not in LONG_FUNCTION_ALLOWED:
                too_long.append(f"{module}.{name}: {length} statements")
    assert too_long == []


def test_sizes_count_statements_not_layout():
    """A call spread over many lines is one statement; 81 statements are too many."""
    one_call = "x = f(\n    1,\n    2,\n    3,\n)\n"
    assert len(_logical_line_ends(one_call)) == 1
    body = "".join(f"    a{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    text = f"def g():\n{body}"
    ends = _logical_line_ends(text)
    assert dict(_functions(ast.parse(text), ends)) == {"g": MAX_FUNCTION_LINES + 1}
