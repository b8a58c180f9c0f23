"""The twenty-third hostile pass (camera-alone runs; the documentation and benchmark
scripts as a user follows them) and taste leftovers of earlier passes: each test
reproduces a finding, then checks what the toolkit does now."""

from __future__ import annotations

import os

from graphslam.cli.main import main
from slamcore.errors import ConfigError

SWEEP = '[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = [0, 1, 2, 3]\nmax_steps = 5\nnees = false\n'


def test_more_workers_than_cores_is_said(tmp_path, monkeypatch, capsys):
    """--workers 1000 on two cores started them all, unsaid (a taste of pass 21)."""
    from graphslam.pipelines import sweep_exec

    asked = []

    class Fake:
        def __init__(self, workers):
            asked.append(workers)
            raise ConfigError("stop here")

    monkeypatch.setattr(sweep_exec, "PoolExecutor", Fake)
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    (tmp_path / "s.toml").write_text(SWEEP)
    assert main(["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--workers", "1000"]) == 2
    assert asked == [4]  # capped at the runs, as before
    assert "--workers 4 on 2 cores: the runs share them" in capsys.readouterr().err
