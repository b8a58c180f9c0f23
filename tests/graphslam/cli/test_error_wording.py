"""Errors that named the wrong flag or the wrong cause (the seventh hostile pass's
leftovers): each is one line that names what the user gave and what would do."""

from __future__ import annotations

import pytest

from graphslam.cli.main import main
from tests.graphslam.cli.test_hostile_inputs import one_error_line as _one_error

DATA = __import__("pathlib").Path(__file__).resolve().parents[4] / "shared" / "data"


@pytest.mark.parametrize("command", ["run", "compare"])
@pytest.mark.parametrize("seed, said", [("-1", "from 0 to 2**62, got -1"), ("x", "whole number, got 'x'")])
def test_a_seed_no_run_takes_is_the_flags_error(tmp_path, capsys, command, seed, said):
    with pytest.raises(SystemExit) as stop:  # the parser's one line, as for every flag
        main([command, "--seed", seed, "--out", str(tmp_path / "o"), "--rerun", "off"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1 and err.startswith("graphslam: error: ")
    assert "argument --seed" in err and said in err and "synthetic.seed" not in err


def test_compare_names_batch_as_pose_graph_only_not_as_unknown(tmp_path, capsys):
    line = _one_error(capsys, ["compare", "--backends", "batch", "ekf-idp", "--out", tmp_path / "o",
                               "--rerun", "off", "--max-steps", "3"])
    assert "not on 2-D landmark datasets; batch: pose-graph files only" in line
    line = _one_error(capsys, ["compare", "--backends", "ekf-idp", "--out", tmp_path / "o",
                               "--rerun", "off", "--max-steps", "3"])
    assert "pose-graph" not in line  # the hint only where it applies


@pytest.mark.parametrize("given", ["folder", "storage file"])
def test_a_ros2_bag_without_its_metadata_is_said_as_that(tmp_path, capsys, given):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(64))
    spec = bag if given == "folder" else bag / "bag_0.mcap"
    line = _one_error(capsys, ["run", "--dataset", spec, "--out", tmp_path / "o", "--rerun", "off"])
    assert "needs the metadata.yaml" in line and str(bag) in line


def test_a_folder_of_images_with_a_stray_storage_file_is_still_images(tmp_path):
    from graphslam.sources.spatial.rosbag import bag_path

    (tmp_path / "0001.png").write_bytes(b"")
    (tmp_path / "notes.db3").write_bytes(b"")
    assert bag_path(tmp_path) is None  # read as the image folder it is, no refusal
