"""The linter runs with the suite (issue 36): pyflakes' checks (unused imports and
variables, undefined names, f-strings without fields) and syntax errors, over every
package, the benchmarks and the tests. ``ruff`` is in the ``test`` extra."""

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
