"""What a run says about its images (the fifth hostile pass): the reader's doubts reach
metrics.json ``warnings`` (run and localize), and a run with odometry whose images gave
no landmark says that its trajectory is the odometry alone."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from frontend.tracking import Tracker
from frontend.tracking_config import TrackerConfig
from graphslam.pipelines import localize_run
from graphslam.pipelines import spatial as vp
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
from tests.graphslam.pipelines.test_visual_pipeline import QVGA, TruthBackend


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_images(SyntheticImagesConfig(**QVGA, n_frames=20))


def test_the_readers_doubts_reach_the_metrics(seq):
    doubted = dataclasses.replace(seq, camera_warnings=("a camera of another size",))
    result = vp.run(doubted, TruthBackend(doubted), Tracker(TrackerConfig(), follow_unmapped=False),
                    max_frames=6)
    assert vp.compute_metrics(result).to_dict()["warnings"][0] == "a camera of another size"
    placed = localize_run.LocalizeResult(doubted)
    assert localize_run.compute_metrics(placed, {})["warnings"] == ["a camera of another size"]
    assert "warnings" not in localize_run.compute_metrics(localize_run.LocalizeResult(seq), {})


def _result(odometry: str, landmarks: int, frames: int = 5):
    estimate = SimpleNamespace(frame_ids=np.arange(frames), landmark_ids=np.arange(landmarks), stats={})
    tracking = {"corners": [40] * frames, "observations": [0] * frames, "found": [0] * frames}
    return SimpleNamespace(frames=frames, estimate=estimate, odometry=odometry, tracking=tracking)


def test_no_landmark_with_odometry_is_said():
    (line,) = vp._doubts(_result("derived", 0))
    assert "no landmark entered the map in 5 frames" in line and "odometry alone" in line
    assert vp._doubts(_result("derived", 3)) == []
    assert vp._doubts(_result("derived", 0, frames=1)) == []  # one frame: nothing to correct
    assert "found no corner" not in line
    no_corner = _result("derived", 0)
    no_corner.tracking["corners"] = [0] * 5
    (line,) = vp._doubts(no_corner)
    assert "(0 corners detected, 0 matched in all)" in line and "the detector found no corner" in line


def _kitti07(shared_data, n: int) -> np.ndarray:
    """(n, 4, 4) camera-to-world truth of KITTI 07's first frames."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3] = np.loadtxt(shared_data / "kitti07" / "poses.txt")[:n].reshape(-1, 3, 4)
    return T


def _scored(truth: np.ndarray, estimate: np.ndarray):
    from graphslam.evaluation import spatial as metrics3d

    n = len(truth)
    result = SimpleNamespace(estimate=SimpleNamespace(frame_ids=np.arange(n), wTc=estimate), frames=n,
                             sequence=SimpleNamespace(wTc_true=truth))
    a = metrics3d.ate(np.arange(n), estimate, np.arange(n), truth, alignment="sim3")
    return result, SimpleNamespace(alignment="sim3", ate_rmse_m=a["rmse_m"])


def test_a_truth_of_world_to_camera_poses_is_named_in_the_divergence_warning(shared_data):
    from slamcore.spatial.geometry import invert_pose

    T = _kitti07(shared_data, 60)
    wobble = T.copy()
    wobble[:, :3, 3] += 0.05 * np.sin(np.arange(60))[:, None]  # an honest estimate, 5 cm off
    said = vp._inverted_truth(*_scored(invert_pose(T), wobble))
    assert "truth holds world-to-camera poses" in said
    # the truth as it should be: nothing to explain; an estimate lost anyway: not blamed on the truth
    assert vp._inverted_truth(*_scored(T, wobble)) == ""
    lost = np.tile(np.eye(4), (60, 1, 1))
    lost[:, :3, 3] = np.random.default_rng(0).normal(0.0, 20.0, (60, 3))
    assert vp._inverted_truth(*_scored(invert_pose(T), lost)) == ""
