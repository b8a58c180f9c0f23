"""The command line end to end: outputs, one-line errors, Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from graphslam.cli.main import main
from tests.conftest import ROOT

METRIC_KEYS = {"dataset", "backend", "steps", "landmarks", "final_error", "ate_rmse_m",
               "wall_s", "steps_per_s"}


def run_cli(args, tmp_path, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "graphslam.cli.main", *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=timeout, env=env)


def assert_one_line_error(proc, *fragments):
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr  # one line, never a traceback
    assert lines[0].startswith("graphslam: error:")
    for frag in fragments:
        assert frag in lines[0]


def test_help_explains(capsys):
    with pytest.raises(SystemExit) as e:
        main(["run", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for word in ("victoria-park", "city10000", "trajectory.tum", "metrics.json", "--rerun"):
        assert word in out


def test_synthetic_run_writes_outputs(tmp_path):
    out = tmp_path / "out"
    proc = run_cli(["run", "--max-steps", "150", "--out", str(out), "--quiet"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert f"outputs in {out}" in proc.stdout
    m = json.loads((out / "metrics.json").read_text())
    assert METRIC_KEYS <= set(m)
    assert m["steps"] == 150 and m["dataset"] == "synthetic" and m["backend"] == "isam2"
    assert m["ate_rmse_m"] is not None and m["final_error"] > 0
    tum = (out / "trajectory.tum").read_text().splitlines()
    assert len([line for line in tum if not line.startswith("#")]) == 150
    assert (out / "landmarks.csv").read_text().startswith("id,x,y\n")
    assert (out / "run.rrd").stat().st_size > 1000


def test_same_seed_same_bits(tmp_path):
    outs = []
    for name in ("a", "b"):
        proc = run_cli(["run", "--max-steps", "60", "--seed", "4", "--out", name, "--rerun",
                        "off", "--quiet"], tmp_path)
        assert proc.returncode == 0, proc.stderr
        outs.append((tmp_path / name / "trajectory.tum").read_bytes())
    assert outs[0] == outs[1]


def test_missing_file_is_one_line(tmp_path):
    proc = run_cli(["run", "--dataset", "nope.graph", "--rerun", "off"], tmp_path)
    assert_one_line_error(proc, "nope.graph")


def test_malformed_pose_graph_names_file_and_line(tmp_path):
    bad = tmp_path / "bad.graph"
    bad.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 zero 1 0 1 1 0 0\n")
    proc = run_cli(["run", "--dataset", str(bad), "--rerun", "off"], tmp_path)
    assert_one_line_error(proc, "bad.graph:3")


def test_nan_measurement_is_refused(tmp_path):
    bad = tmp_path / "nan.graph"
    bad.write_text("EDGE2 0 1 1 0 nan 1 0 1 1 0 0\n")
    proc = run_cli(["run", "--dataset", str(bad), "--rerun", "off"], tmp_path)
    assert_one_line_error(proc, "nan.graph:1")


def test_bad_config_is_one_line(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[isam2]\nrelinearize_treshold = 0.1\n")  # typo must not pass silently
    proc = run_cli(["run", "--config", str(cfg), "--rerun", "off"], tmp_path)
    assert_one_line_error(proc, "relinearize_treshold")


@pytest.mark.slow
def test_ctrl_c_writes_what_was_estimated(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "graphslam.cli.main", "run", "--dataset",
                             "victoria-park", "--out", "vp", "--rerun", "off", "--quiet"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    time.sleep(8.0)  # imports and reading take ~2 s; the full run takes far longer
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    m = json.loads((tmp_path / "vp" / "metrics.json").read_text())
    assert m["interrupted"] is True
    assert 1 < m["steps"] < 6969
    rows = [r for r in (tmp_path / "vp" / "trajectory.tum").read_text().splitlines()
            if not r.startswith("#")]
    assert len(rows) == m["steps"]


def test_a_path_option_starting_with_a_tilde_is_in_the_home_folder(monkeypatch, tmp_path):
    # "--out=~/runs": the shell leaves the ~ (it expands one only at a word's start);
    # a folder named ~ was made in the current one while the summary said ~/runs
    from pathlib import Path

    from graphslam.cli.common import path_arg

    monkeypatch.setenv("HOME", str(tmp_path))
    assert path_arg("~/runs") == tmp_path / "runs"
    assert path_arg("a/~b") == Path("a/~b")
