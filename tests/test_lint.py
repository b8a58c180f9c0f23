"""The linter and the type checker run with the suite (issue 36): pyflakes' checks
(unused imports and variables, undefined names, f-strings without fields) and syntax
errors over every package, the benchmarks and the tests; mypy over the library
packages. ``ruff`` and ``mypy`` are in the ``test`` extra."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: What is linted: the library packages, the benchmarks, the tests.
LINTED = ["graphslam", "frontend", "loopclosure", "filters", "slamcore", "datasets", "benchmarks",
          "tests"]


def test_ruff_finds_nothing():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.fail("ruff is not installed: pip install -e '.[test]'")
    proc = subprocess.run([ruff, "check", "--select", "E9,F", "--output-format", "concise",
                           *LINTED], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_finds_nothing(tmp_path):
    """The type checker over the library packages (``[tool.mypy]`` in pyproject.toml:
    slamcore, frontend, loopclosure, filters, graphslam), its cache in a fresh folder so
    a run never reads another's half-written cache."""
    proc = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "cache")],
                          cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "Success: no issues found" in proc.stdout
