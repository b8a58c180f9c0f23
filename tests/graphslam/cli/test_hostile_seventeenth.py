"""The seventeenth hostile pass (2026-12-04): findings of the sixteenth left open, and
the new pass's. Each test reproduces a finding, then checks what the code does now."""

from __future__ import annotations

from pathlib import Path

from graphslam.pipelines.sweep_spec import parse_sweep


def _sweep_file(tmp_path: Path, extra: str = "") -> Path:
    import gtsam

    graph = gtsam.findExampleDataFile("noisyToyGraph.txt")
    path = tmp_path / "sweep.toml"
    path.write_text(f'[sweep]\ndataset = ["synthetic", "{graph}"]\nbackend = ["isam2"]\n{extra}')
    return path


def test_a_mixed_sweep_says_its_synthetic_runs_score_no_nees(tmp_path):
    """dataset = ["synthetic", a pose graph]: NEES off by default for every run, the
    synthetic ones included, and nothing said (hostile pass 16)."""
    spec = parse_sweep(_sweep_file(tmp_path))
    assert spec.nees is False
    assert len(spec.notes) == 1 and "nees = true" in spec.notes[0]
    assert all(not r.nees for r in spec.runs())


def test_a_sweep_that_chose_its_nees_is_told_nothing(tmp_path):
    assert parse_sweep(_sweep_file(tmp_path, "nees = false\n")).notes == ()
    only = tmp_path / "only.toml"
    only.write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\n')
    spec = parse_sweep(only)
    assert spec.nees is True and spec.notes == ()
