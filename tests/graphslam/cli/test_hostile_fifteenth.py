"""The fifteenth hostile pass (repeatability and provenance): each test reproduces a
finding that was silent, then checks what the toolkit does now."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from graphslam.cli.main import main

ROOT = Path(__file__).resolve().parents[3]


def test_a_run_records_where_and_with_what_it_ran(tmp_path):
    """metrics.json said ``graphslam`` for ``python -m graphslam``, and neither the working
    directory its relative paths are read from nor any version."""
    (tmp_path / "c.toml").write_text("[isam2]\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run(
        [sys.executable, "-m", "graphslam", "run", "--max-steps", "5", "--config", "c.toml", "--rerun", "off",
         "--quiet", "--out", "o", "--save-map", "m"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    prov = json.loads((tmp_path / "o" / "metrics.json").read_text())["provenance"]
    assert prov["command"][:4] == [Path(sys.executable).name, "-m", "graphslam", "run"]
    assert prov["cwd"] == os.path.realpath(tmp_path)
    assert prov["config_file"] == "c.toml" and prov["config_file_resolved"] == os.path.realpath(tmp_path / "c.toml")
    assert set(prov["versions"]) == {"graphslam", "gtsam", "numpy", "opencv", "python"}
    assert prov["versions"]["gtsam"] and len(prov["code_sha256"]) == 64
    saved = json.loads((tmp_path / "m" / "map.json").read_text())["meta"]["provenance"]
    assert saved["cwd"] == prov["cwd"] and saved["code_sha256"] == prov["code_sha256"]


def test_eval_json_records_where_and_with_what_it_ran(tmp_path, monkeypatch, capsys):
    for name in ("gt.tum", "est.tum"):
        (tmp_path / name).write_text("".join(f"{t} {t} 0 0 0 0 0 1\n" for t in range(5)))
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "gt.tum", "est.tum", "--out", "e", "--no-plot"]) == 0
    prov = json.loads((tmp_path / "e" / "eval.json").read_text())["provenance"]
    assert prov["command"][:2] == ["graphslam", "eval"] and prov["cwd"] == os.path.realpath(tmp_path)
    assert prov["versions"]["numpy"]


@pytest.mark.parametrize("argv0", ["graphslam"])
def test_main_called_from_python_stands_for_the_command(argv0):
    from graphslam.pipelines.provenance import invoked_as

    assert invoked_as() == [argv0]  # pytest's __main__ is no graphslam module
