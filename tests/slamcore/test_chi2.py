"""``slamcore.chi2``: the quantiles ``scipy.stats.chi2`` gives, bit for bit, and a plain
run that no longer imports ``scipy.stats`` (about 0.8 s of every process) nor the
visual pipeline."""

from __future__ import annotations

import subprocess
import sys

import pytest
from scipy.stats import chi2 as reference

from slamcore import chi2
from tests.conftest import ROOT

DOFS = [1, 2, 3, 4, 6, 9, 15, 100, 3000, 2.5]
PROBS = [1e-12, 1e-4, 0.01, 0.025, 0.05, 0.5, 0.95, 0.975, 0.99, 0.9999, 1 - 1e-9]


@pytest.mark.parametrize("dof", DOFS)
def test_the_same_bits_as_scipy_stats(dof):
    for p in PROBS:
        assert chi2.ppf(p, dof) == float(reference.ppf(p, dof))
        assert chi2.isf(p, dof) == float(reference.isf(p, dof))
    assert chi2.median(dof) == float(reference.median(dof))


def test_a_plain_2d_run_imports_neither_scipy_stats_nor_the_visual_pipeline(tmp_path):
    """Import costs of every command: ``scipy.stats`` (0.8 s) and, through the
    ``compare`` parser's odometry choices, the visual pipeline and its tracker (0.2 s)."""
    heavy = ["scipy.stats", "graphslam.pipelines.spatial", "frontend.tracking"]
    code = ("import sys; from graphslam.cli.main import main; "
            f"rc = main(['run', '--max-steps', '20', '--rerun', 'off', '--quiet', '--out', {str(tmp_path)!r}]); "
            f"print(rc, *[m in sys.modules for m in {heavy!r}])")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert done.stdout.split()[-4:] == ["0", "False", "False", "False"], done.stdout + done.stderr
