"""Eleventh hostile pass (2026-11-30): what a hostile but plausible user found, one test a fix.

Run in process through :func:`graphslam.cli.main.main`, which turns errors into one
``graphslam: error:`` line and exit status 2.
"""

from __future__ import annotations

import json

from graphslam.cli.main import main


def test_the_first_monocular_map_names_the_files_frame_under_frames(tmp_path, capsys):
    """Under ``--frames 3:`` the summary said "monocular map started frame 2", the run's
    count: a user looks for file frame 5."""
    out = tmp_path / "o"
    argv = ["run", "--dataset", "synthetic-images", "--odometry", "none", "--frames", "3:16",
            "--quiet", "--rerun", "off", "--out", str(out)]
    assert main(argv) == 0
    said = capsys.readouterr().out
    first = json.loads((out / "metrics.json").read_text())["backend_stats"]["camera_alone"]["first_map"]
    assert first["file_frame"] == first["frame"] + 3
    assert f"frame {first['frame']} of the run (file frame {first['frame'] + 3})" in said
