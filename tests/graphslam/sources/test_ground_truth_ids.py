"""``--ground-truth`` read by frame index or pose id (fourth hostile pass): a TUM truth
in seconds given to a sequence without image times, or to a 2-D dataset or pose
graph without timestamps, had its time column read as frame indices or pose ids
(truth at 10 Hz from 0 s gave frame k the truth of k s, row 10 k: a run of 16
frames scored against 80 m of path, exit 0, no word). Now refused, file named."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam.pipelines.posegraph import ground_truth_of
from graphslam.sources.ground_truth import planar_ground_truth, read_trajectory, with_ground_truth
from graphslam.sources.planar.posegraph import read_pose_graph
from graphslam.sources.posegraph_files import read_pose_graph_file
from graphslam.sources.spatial.sequence import ImageSequence
from slamcore.errors import InputError


def _truth(path, stamps):
    path.write_text("".join(f"{t:.6f} {t} 0 0 0 0 0 1\n" for t in stamps))
    return read_trajectory(path)


def _folder_sequence(n: int) -> ImageSequence:
    return ImageSequence("folder-imgs", [f"{k:02d}.png" for k in range(n)], None,
                         np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), None, None, (640, 480))


def _chain(tmp_path, n: int):
    path = tmp_path / "chain.g2o"
    path.write_text("".join(f"EDGE_SE2 {k} {k + 1} 1 0 0 100 0 0 100 0 1000\n" for k in range(n - 1)))
    return path


def test_seconds_for_a_sequence_without_times_are_refused(tmp_path):
    truth = _truth(tmp_path / "gt.tum", np.arange(160) * 0.103875)
    with pytest.raises(InputError, match="read as frame indices .* 0.103875 is not a whole number") as e:
        with_ground_truth(_folder_sequence(16), truth)
    assert "gt.tum" in str(e.value)
    by_index = with_ground_truth(_folder_sequence(16), _truth(tmp_path / "idx.tum", np.arange(160.0)))
    np.testing.assert_array_equal(by_index.wTc_true[:, 0, 3], np.arange(16.0))  # frame k, row k


def test_seconds_for_a_planar_dataset_without_timestamps_are_refused(tmp_path):
    dataset = read_pose_graph(_chain(tmp_path, 12))
    with pytest.raises(InputError, match="read as pose ids .* 0.1 is not a whole number"):
        planar_ground_truth(dataset, _truth(tmp_path / "gt.tum", np.arange(0, 20, 0.1)))
    ids, _ = planar_ground_truth(dataset, _truth(tmp_path / "ids.tum", np.arange(12.0)))
    np.testing.assert_array_equal(ids, np.arange(12))


def test_seconds_for_a_pose_graph_are_refused(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text("".join(f"VERTEX_SE2 {k} {k} 0 0\n" for k in range(5))
                    + "".join(f"EDGE_SE2 {k} {k + 1} 1 0 0 1 0 0 1 0 1\n" for k in range(4)))
    g = read_pose_graph_file(path)
    with pytest.raises(InputError, match="read as pose ids, and 0.5 is not a whole number"):
        ground_truth_of(g, _truth(tmp_path / "gt.tum", np.arange(0, 5, 0.5)))
    ids, _ = ground_truth_of(g, _truth(tmp_path / "ids.tum", np.arange(5.0)))
    np.testing.assert_array_equal(ids, np.arange(5))
