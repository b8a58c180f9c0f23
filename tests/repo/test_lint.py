"""The linter and the type checker run with the suite (issue 36): ruff with the
rules of ``[tool.ruff.lint]`` in pyproject.toml (pycodestyle, pyflakes, bugbear
(``zip`` without ``strict=`` among them), import order, pyupgrade) over the library
packages, whose layout is ``ruff format``'s (``ruff format --check``); pyflakes'
checks and syntax errors over the benchmarks and the tests;
mypy over the library packages. ``ruff`` and ``mypy`` are in the ``test`` extra."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

#: Linted with pyproject's rules.
LIBRARY = ["graphslam", "frontend", "loopclosure", "filters", "slamcore", "datasets"]
#: Linted for syntax errors and pyflakes' findings only (scripts around the library).
OTHERS = ["benchmarks", "tests"]


def test_ruff_finds_nothing():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.fail("ruff is not installed: pip install -e '.[test]'")
    for args in (["check", "--output-format", "concise", *LIBRARY],
                 ["check", "--select", "E9,F", "--output-format", "concise", *OTHERS],
                 ["format", "--check", *LIBRARY]):
        proc = subprocess.run([ruff, *args], cwd=ROOT, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_finds_nothing(tmp_path):
    """The type checker over the library packages (``[tool.mypy]`` in pyproject.toml:
    slamcore, frontend, loopclosure, filters, graphslam), its cache in a fresh folder so
    a run never reads another's half-written cache."""
    proc = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "cache")],
                          cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "Success: no issues found" in proc.stdout
