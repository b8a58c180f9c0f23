"""Thirteenth hostile pass (2026-12-01): settings on their way to a run, the figures of
compare and sweep, saved maps and localisation, large inputs. One test a fix.

Run in process through :func:`graphslam.cli.main.main`, which turns errors into one
``graphslam: error:`` line and exit status 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from graphslam.cli.main import main

RUN = ["--rerun", "off", "--quiet"]


def test_compare_records_the_seed_the_config_file_gave(tmp_path):
    """``[synthetic] seed = 2`` ran seed 2 and compare.json said ``"seed": null``."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[synthetic]\nseed = 2\n")
    out = tmp_path / "o"
    assert main(["compare", "--config", str(cfg), "--backends", "isam2", "--max-steps", "20",
                 "--rerun", "off", "--out", str(out)]) == 0
    runs = json.loads((out / "compare.json").read_text())["runs"]
    assert runs[0]["seed"] == 2


def test_robot_flag_wins_over_a_file_running_all_robots(tmp_path, capsys, shared_data):
    """``--robot 2`` under ``[mrclam] all_robots = true`` ran the five robots, silent."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[mrclam]\nall_robots = true\n")
    out = tmp_path / "o"
    assert main(["run", "--dataset", str(shared_data / "mrclam6"), "--robot", "2", "--config", str(cfg),
                 "--max-steps", "30", *RUN, "--out", str(out)]) == 0
    assert json.loads((out / "metrics.json").read_text())["dataset"] == "mrclam6-robot2"
    assert "[mrclam] all_robots did nothing: the command line's false" in capsys.readouterr().err
