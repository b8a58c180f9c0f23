"""A wheel file whose noise convention is known is read by it and says so (issue 35:
the README's sphere2500 example ended at 364.49 without a word); a closed pipe on
stdout ends the command quietly (issue 34)."""

from __future__ import annotations

import json
import subprocess
import sys

import gtsam
import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.sources.posegraph_files import read_pose_graph_file

SPHERE = gtsam.findExampleDataFile("sphere2500.txt")


def test_auto_reads_sphere2500_as_square_root_information_and_says_so(tmp_path):
    auto = read_pose_graph_file(SPHERE)
    sqrt = read_pose_graph_file(SPHERE, "sqrt_information")
    plain = read_pose_graph_file(SPHERE, "information")
    assert auto.noise == "sqrt_information" and "sphere2500" in auto.noise_note
    assert np.array_equal(auto.information, sqrt.information)
    assert plain.noise == "information" and plain.noise_note is None
    # recognised by content, not by name: a copy with one number changed is not it
    text = open(SPHERE).read()
    other = tmp_path / "sphere2500.txt"
    other.write_text(text.replace("10", "11", 1))
    g = read_pose_graph_file(other)
    assert g.noise == "information" and g.noise_note is None


def test_the_run_summary_and_metrics_name_the_convention(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--dataset", SPHERE, "--backend", "batch", "--init", "chordal",
                 "--max-steps", "300", "--rerun", "off", "--quiet", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "edge numbers read as   sqrt_information (auto: gtsam's sphere2500.txt" in text
    m = json.loads((out / "metrics.json").read_text())
    assert m["noise"].startswith("sqrt_information (auto")
    # a file the table does not know: nothing to say
    w100 = gtsam.findExampleDataFile("w100.graph")
    assert main(["run", "--dataset", w100, "--backend", "batch", "--rerun", "off", "--quiet",
                 "--out", str(tmp_path / "w")]) == 0
    assert "edge numbers read as" not in capsys.readouterr().out
    assert "noise" not in json.loads((tmp_path / "w" / "metrics.json").read_text())


@pytest.mark.skipif(sys.platform == "win32", reason="SIGPIPE semantics")
def test_a_closed_stdout_pipe_is_a_quiet_exit_with_every_file_written(tmp_path):
    w100 = gtsam.findExampleDataFile("w100.graph")
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "graphslam", "run", "--dataset", w100,
                             "--backend", "batch", "--rerun", "off", "--quiet", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader leaves before the summary (| head -0)
    err = proc.stderr.read().decode()
    assert proc.wait() == 141, err
    assert "Traceback" not in err
    assert {p.name for p in out.iterdir()} >= {"trajectory.tum", "metrics.json"}
