"""Tracking loss inside a SLAM run: ten black frames in the middle of the synthetic room.

The run (visual iSAM2, the sequence's odometry) must be placed again within
:data:`RECOVER_FRAMES` frames after the blackout: by active search on the
odometry's prediction, or, when search is not trusted (``min_found`` = 6:
before the blackout it finds 9-10 landmarks a frame, the four it finds just
after do not count), by relocalisation against the run's own map.
"""

from __future__ import annotations

import numpy as np
import pytest

from frontend.tracking import Tracker
from graphslam import registry
from graphslam.pipelines import spatial as vp
from graphslam.pipelines.relocalise import RelocaliseConfig, RunRelocaliser
from graphslam.sources.spatial.frames import black_out, parse_frames, select_frames

BLACK = range(30, 40)
#: Frames after the last black one within which the camera is placed again.
RECOVER_FRAMES = 3
#: Largest error of the relocalised pose against the truth, metres.
RELOC_TOL_M = 0.15


def blackout_run(config: RelocaliseConfig):
    seq = registry.load_image_sequence("synthetic-images")
    seq = black_out(select_frames(seq, parse_frames("0:50")), BLACK)
    backend = registry.make_visual_backend("isam2")
    reloc = RunRelocaliser(seq.K, config)
    result = vp.run(seq, backend, Tracker(follow_unmapped=True), on_frame=reloc)
    return seq, result, reloc.stats


def test_blackout_is_counted_and_recovered():
    _, _, stats = blackout_run(RelocaliseConfig())
    assert stats["losses"] >= 1 and stats["lost_frames"] >= len(BLACK)
    # the loss runs from the last good frame (29) to the frame placed again
    assert stats["loss_lengths"][0] <= len(BLACK) + RECOVER_FRAMES


def test_relocalisation_places_the_frame_after_the_blackout():
    seq, result, stats = blackout_run(RelocaliseConfig(min_found=6))
    assert stats["relocalisations"] >= 1
    assert stats["loss_lengths"][0] <= len(BLACK) + RECOVER_FRAMES
    k = 29 + stats["loss_lengths"][0]  # the relocalised frame
    est = result.estimate
    i = int(np.flatnonzero(est.frame_ids == k)[0])
    assert np.linalg.norm(est.wTc[i, :3, 3] - seq.wTc_true[k][:3, 3]) <= RELOC_TOL_M


def test_relocalise_config_is_checked():
    from slamcore.errors import ConfigError

    with pytest.raises(ConfigError):
        RelocaliseConfig(min_inliers=3)
