"""The fifteenth hostile pass (repeatability and provenance): each test reproduces a
finding that was silent, then checks what the toolkit does now."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from graphslam.cli.main import main

ROOT = Path(__file__).resolve().parents[3]


def test_a_session_joined_twice_is_said_however_it_is_spelled(tmp_path, monkeypatch):
    """The same frames via a relative path, a linked folder, ``0:40:1`` or ``:40`` gave no
    warning, and the joined map held them twice."""
    from graphslam.maps.merge import repeated_session

    data = tmp_path / "data" / "kitti07"
    data.mkdir(parents=True)
    (tmp_path / "link").symlink_to(data)
    # a map saved before the fix: the source and --frames as typed
    old = SimpleNamespace(meta={"dataset": "kitti-kitti07", "source": str(data), "frames": "0:40", "n_frames": 40})
    monkeypatch.chdir(tmp_path / "data")

    def again(source: str, frames: str | None, ran: list[int]) -> int | None:
        meta = {"dataset": "kitti-x", "source": source, "source_path": os.path.realpath(source),
                "frames": frames, "frame_range": ran, "n_frames": ran[1] - ran[0] + 1}
        return repeated_session(old, meta, 160)

    assert again("kitti07", "0:40", [0, 39, 1]) == 0
    assert again(str(tmp_path / "link"), "0:40", [0, 39, 1]) == 0
    assert again(str(data), "0:40:1", [0, 39, 1]) == 0
    assert again(str(data), ":40", [0, 39, 1]) == 0
    assert again(str(data), "0:20", [0, 19, 1]) is None
    assert again(str(data), "0:40:2", [0, 38, 2]) is None
    # an old map's own relative spelling is read from here
    old.meta["source"] = "kitti07"
    assert again(str(tmp_path / "link"), ":40", [0, 39, 1]) == 0


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
