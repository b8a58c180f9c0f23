"""Plots on a machine whose home cannot be written (a batch node, a home on a share
that is not mounted): matplotlib printed a paragraph on stderr in every command."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]

PLOT = """
import os
from graphslam.visualisation.plots import _pyplot
plt = _pyplot()
fig = plt.figure()
fig.savefig(os.devnull, format="png")
print(os.environ.get("MPLCONFIGDIR", ""))
"""


def _plot(**env: str) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if k not in ("MPLCONFIGDIR", "XDG_CONFIG_HOME", "XDG_CACHE_HOME")}
    return subprocess.run([sys.executable, "-c", PLOT], env={**base, "PYTHONPATH": str(ROOT), **env},
                          capture_output=True, text=True, timeout=120)


def test_an_unwritable_config_folder_gives_matplotlib_a_private_one_silently(tmp_path):
    # /dev/null is no folder: even root cannot make one under it
    done = _plot(XDG_CONFIG_HOME="/dev/null", XDG_CACHE_HOME=str(tmp_path / "cache"))
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    private = done.stdout.strip()
    assert Path(private).name.startswith("graphslam-matplotlib-")
    assert not Path(private).exists()  # removed at exit


def test_a_writable_config_folder_is_left_to_matplotlib(tmp_path):
    done = _plot(XDG_CONFIG_HOME=str(tmp_path / "config"), XDG_CACHE_HOME=str(tmp_path / "cache"))
    assert done.returncode == 0 and done.stderr == "" and done.stdout.strip() == ""
