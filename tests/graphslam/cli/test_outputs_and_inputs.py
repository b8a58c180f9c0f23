"""Seventh hostile pass: commands that wrote over, or removed as an earlier run's
output, one of their own input files, and ``compare`` that kept its back ends' doubts
to compare.json without a word."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam.cli.main import main
from tests.graphslam.cli.test_hostile_inputs import one_error_line as _one_error


def test_a_run_does_not_replace_the_ground_truth_it_reads(tmp_path, capsys):
    out = tmp_path / "o"
    argv = ["run", "--max-steps", "5", "--rerun", "off", "--quiet", "--out", out]
    assert main([str(a) for a in argv]) == 0
    truth = (out / "ground_truth.tum").read_bytes()
    line = _one_error(capsys, [*argv, "--ground-truth", out / "ground_truth.tum"])
    assert "ground_truth.tum is the input --ground-truth" in line
    assert (out / "ground_truth.tum").read_bytes() == truth


@pytest.mark.parametrize("write_bag", [False, True])
def test_a_run_neither_removes_nor_overwrites_the_bag_it_reads(tmp_path, capsys, write_bag):
    pytest.importorskip("rosbags")
    from tests.graphslam.sources.test_rosbag import small_bag

    out = tmp_path / "o"
    out.mkdir()
    bag = small_bag(out / "trajectory.bag", "ros1")  # named as the bag --write-bag writes
    data = bag.read_bytes()
    argv = ["run", "--dataset", bag, "--rerun", "off", "--quiet", "--out", out]
    line = _one_error(capsys, argv + ["--write-bag"] * write_bag)
    assert "trajectory.bag is the input --dataset" in line
    assert bag.read_bytes() == data


@pytest.mark.parametrize("flag", ["--out", "--log"])
def test_loops_does_not_write_over_one_of_its_images(tmp_path, capsys, flag):
    import cv2

    imgs = tmp_path / "imgs"
    imgs.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(imgs / f"{k:02d}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    before = (imgs / "01.png").read_bytes()
    other = tmp_path / ("l.csv" if flag == "--log" else "l.jsonl")
    argv = ["loops", imgs, flag, imgs / "01.png", "--log" if flag == "--out" else "--out", other, "--quiet"]
    # --frames leaves 01.png out of the detection: it is still the folder's image
    line = _one_error(capsys, [*argv, "--frames", "1:3" if flag == "--out" else "0:1"])
    assert f"{flag} {imgs / '01.png'} is the input image" in line
    assert (imgs / "01.png").read_bytes() == before


def _degrees_square(tmp_path):
    lines = [f"VERTEX_SE2 {k} 0 0 0" for k in range(4)]
    lines += [f"EDGE_SE2 {k} {(k + 1) % 4} 1 0 90 100 0 0 100 0 1000" for k in range(4)]
    path = tmp_path / "deg.g2o"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("backends", [["isam2", "ekf"], ["batch", "auto"]])
def test_compare_says_the_doubts_its_runs_carry(tmp_path, capsys, backends):
    """A file in degrees: run warns; compare kept the warning to compare.json alone.
    A doubt every back end shares is said once; one back end's with its name."""
    out = tmp_path / "c"
    argv = ["compare", "--dataset", _degrees_square(tmp_path), "--rerun", "off", "--in-process",
            "--out", out, "--backends", *backends]
    assert main([str(a) for a in argv]) == 0
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("graphslam: warning:")]
    degrees = [ln for ln in warnings if "angles in degrees?" in ln]
    assert len(degrees) == 1 and not any(f" {b}: 4 of 4" in degrees[0] for b in backends), warnings
    runs = json.loads((out / "compare.json").read_text())["runs"]
    said = {w for r in runs for w in r.get("warnings") or []}
    assert all(any(w in ln for ln in warnings) for w in said)
    if "isam2" in backends:  # its own doubt (the chi-square bound) named by back end
        assert any(ln.startswith("graphslam: warning: isam2: final cost") for ln in warnings), warnings


@pytest.mark.parametrize("argv, name", [
    (["compare", "--max-steps", "20", "--backends", "isam2", "ekf"], "compare.rrd"),
    (["run", "--dataset", "synthetic-images", "--max-steps", "8"], "run.rrd"),
    (["run", "--dataset", "w100.graph"], "run.rrd"),
])
def test_a_recording_that_could_not_be_written_is_not_listed(tmp_path, capsys, monkeypatch, argv, name):
    """A full disk while Rerun writes the recording: the warning says none is kept,
    and the outputs line does not name it (compare, the visual and pose-graph runs
    listed it all the same)."""
    from graphslam.visualisation import recording

    def full_disk(self):
        self.discard()
        raise recording.ViewerUnavailable(f"the recording could not be written (test); no {name} is kept")

    monkeypatch.setattr(recording.RerunLog, "close", full_disk)
    if "w100.graph" in argv:
        gtsam = pytest.importorskip("gtsam")
        argv = [a if a != "w100.graph" else gtsam.findExampleDataFile("w100.graph") for a in argv]
    out = tmp_path / "o"
    quiet = [] if argv[0] == "compare" else ["--quiet"]
    assert main([str(a) for a in [*argv, "--rerun", "save", *quiet, "--out", out]]) == 0
    captured = capsys.readouterr()
    assert f"no {name} is kept" in captured.err
    listed = [ln for ln in captured.out.splitlines() if ln.startswith("outputs in")]
    assert listed and name not in listed[-1] and not (out / name).exists()


def test_write_limit_reached_names_a_file_size_limit_and_a_full_file_system(tmp_path, monkeypatch):
    resource = pytest.importorskip("resource")
    import os
    from types import SimpleNamespace

    from graphslam.visualisation.recording import write_limit_reached

    f = tmp_path / "r.rrd"
    f.write_bytes(b"x" * 4096)
    assert write_limit_reached(f) is None  # this disk has room, no limit set
    monkeypatch.setattr(resource, "getrlimit", lambda what: (4096, resource.RLIM_INFINITY))
    assert "file-size limit" in write_limit_reached(f)
    monkeypatch.setattr(resource, "getrlimit", lambda what: (resource.RLIM_INFINITY,) * 2)
    monkeypatch.setattr(os, "statvfs", lambda p: SimpleNamespace(f_bfree=0, f_bavail=0))
    assert write_limit_reached(f) == "no space left on device"


def test_a_recording_that_cannot_start_blames_the_disk_not_a_folders_size(tmp_path, monkeypatch):
    """The writer's start failing was explained by the folder's size against the file-size
    limit: under a limit below a folder's 4 kB, a run on a disk with room was told its
    recording hit that limit. The folder's file system is what can be full there."""
    resource = pytest.importorskip("resource")
    import os
    from types import SimpleNamespace

    import rerun

    from graphslam.visualisation.recording import RerunLog, ViewerUnavailable, disk_full

    def refused(self, path, *args, **kwargs):
        raise RuntimeError("Failed to encode LogMsg: the writer could not start")

    monkeypatch.setattr(rerun.RecordingStream, "save", refused)
    monkeypatch.setattr(resource, "getrlimit", lambda what: (1, resource.RLIM_INFINITY))
    with pytest.raises(ViewerUnavailable) as err:
        RerunLog("save", tmp_path / "run.rrd")
    assert "(Failed to encode LogMsg: the writer could not start)" in str(err.value)
    assert disk_full(tmp_path) is None  # room on this disk, whatever the limit
    monkeypatch.setattr(os, "statvfs", lambda p: SimpleNamespace(f_bfree=0, f_bavail=0))
    assert disk_full(tmp_path) == "no space left on device"
