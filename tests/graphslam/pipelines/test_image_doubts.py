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
    doubted = dataclasses.replace(seq, warnings=("a frame stored twice",))
    result = vp.run(doubted, TruthBackend(doubted), Tracker(TrackerConfig(), follow_unmapped=False),
                    max_frames=6)
    assert vp.compute_metrics(result).to_dict()["warnings"][0] == "a frame stored twice"
    placed = localize_run.LocalizeResult(doubted)
    assert localize_run.compute_metrics(placed, {})["warnings"] == ["a frame stored twice"]
    assert "warnings" not in localize_run.compute_metrics(localize_run.LocalizeResult(seq), {})


def _result(odometry: str, landmarks: int, frames: int = 5):
    estimate = SimpleNamespace(frame_ids=np.arange(frames), landmark_ids=np.arange(landmarks), stats={})
    tracking = {"observations": [0] * frames, "found": [0] * frames}
    return SimpleNamespace(frames=frames, estimate=estimate, odometry=odometry, tracking=tracking)


def test_no_landmark_with_odometry_is_said():
    (line,) = vp._doubts(_result("derived", 0))
    assert "no landmark entered the map in 5 frames" in line and "odometry alone" in line
    assert vp._doubts(_result("derived", 3)) == []
    assert vp._doubts(_result("derived", 0, frames=1)) == []  # one frame: nothing to correct
