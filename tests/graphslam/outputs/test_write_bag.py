"""``graphslam run --write-bag`` (issue 35 item 2): the estimate as a ROS 1 bag that reads
back as the run's own trajectory.tum."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.sources.ground_truth import read_trajectory

pytest.importorskip("rosbags")

#: The bag holds the TUM file's numbers (9 significant digits) as float64.
SAME_M = 1e-9


def test_the_bag_reads_back_as_the_trajectory(tmp_path, capsys):
    from graphslam.sources.spatial.rosbag import read_bag_trajectory

    out = tmp_path / "run"
    assert main(["run", "--dataset", "synthetic", "--max-steps", "40", "--rerun", "off",
                 "--quiet", "--out", str(out), "--write-bag"]) == 0
    assert "PoseStamped on /graphslam/trajectory" in capsys.readouterr().out
    tum = read_trajectory(out / "trajectory.tum", "tum")
    bag = read_bag_trajectory(out / "trajectory.bag", "/graphslam/trajectory")
    assert np.array_equal(bag.stamps_s, tum.stamps_s)
    assert np.abs(bag.wTc - tum.wTc).max() < SAME_M
    # the same folder again without --write-bag: the old bag is not left beside the new run
    assert main(["run", "--dataset", "synthetic", "--max-steps", "10", "--rerun", "off",
                 "--quiet", "--out", str(out)]) == 0
    assert not (out / "trajectory.bag").exists()


def test_a_pose_graph_run_writes_one_pose_per_id(tmp_path, capsys):
    import gtsam

    from graphslam.sources.spatial.rosbag import read_bag_trajectory

    out = tmp_path / "pg"
    assert main(["run", "--dataset", gtsam.findExampleDataFile("w100.graph"), "--backend",
                 "batch", "--rerun", "off", "--quiet", "--out", str(out), "--write-bag"]) == 0
    bag = read_bag_trajectory(out / "trajectory.bag", None)
    assert len(bag.stamps_s) == 100 and bag.stamps_s[0] == 0.0


def test_without_rosbags_write_bag_is_refused_before_the_run(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "rosbags.rosbag1", None)  # import fails as if missing
    out = tmp_path / "never"
    assert main(["run", "--dataset", "synthetic", "--max-steps", "5", "--rerun", "off",
                 "--quiet", "--out", str(out), "--write-bag"]) == 2
    assert 'pip install ".[bags]"' in capsys.readouterr().err
    assert not out.exists()  # nothing ran


def test_evo_reads_the_bag_as_the_trajectory(tmp_path):
    """evo (the trajectory tool robotics users score with) reads the bag ``--write-bag``
    writes: the same stamps and poses as the run's trajectory.tum (issue 35)."""
    pytest.importorskip("evo")
    from evo.tools import file_interface
    from rosbags.rosbag1 import Reader

    out = tmp_path / "run"
    assert main(["run", "--dataset", "synthetic", "--max-steps", "40", "--rerun", "off",
                 "--quiet", "--out", str(out), "--write-bag"]) == 0
    with Reader(out / "trajectory.bag") as reader:
        traj = file_interface.read_bag_trajectory(reader, "/graphslam/trajectory")
    tum = file_interface.read_tum_trajectory_file(str(out / "trajectory.tum"))
    assert traj.num_poses == tum.num_poses >= 40
    np.testing.assert_allclose(traj.timestamps, tum.timestamps, rtol=0, atol=1e-9)
    assert np.abs(traj.positions_xyz - tum.positions_xyz).max() < SAME_M
    # quaternions up to sign (q and -q are one rotation)
    dots = np.abs(np.sum(traj.orientations_quat_wxyz * tum.orientations_quat_wxyz, axis=1))
    assert np.abs(dots - 1.0).max() < SAME_M
