"""benchmarks/synthetic_mono.toml, the monocular EKF on the synthetic room without
odometry: each value checked against what it claims to measure (the sequence's
stamps and ground-truth kinematics, the search gate, the room's depths), and the
whole run (slow)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from filters import landmark_params as lp
from filters.mono_ekf_config import MonoEkfConfig
from frontend.active_search_config import ActiveSearchConfig
from graphslam import registry
from graphslam.pipelines import spatial as vp
from graphslam.sources.spatial.synthetic_images import make_synthetic_images
from tests.conftest import ROOT

CONFIG = ROOT / "benchmarks" / "synthetic_mono.toml"
#: A measured rate written in the file with two significant digits.
RATE_TOL = 0.01
#: The fixed prior's mean depth (2 min_depth_m) vs the room's median depth in view.
DEPTH_TOL = 0.05
#: The run's ATE at most this share of the path (the task's bound; measured 1.42 %).
ATE_PERCENT_MAX = 2.0


@pytest.fixture(scope="module")
def room():
    """The default room, its config sections and per-frame kinematics of its ground truth:
    ``(seq, ekf, search, v (N-1, 3) m/s world, w (N-1, 3) rad/s body)``."""
    seq = make_synthetic_images()
    config = registry.read_config(CONFIG)
    T, dt = seq.wTc_true, np.diff(np.asarray(seq.stamps_s))
    v = np.diff(T[:, :3, 3], axis=0) / dt[:, None]
    w = np.array([lp.q2v(lp.R2q(T[i, :3, :3].T @ T[i + 1, :3, :3]))
                  for i in range(len(T) - 1)]) / dt[:, None]
    return seq, config.section(MonoEkfConfig), config.section(ActiveSearchConfig), v, w


def test_frame_interval_is_the_stamps(room):
    seq, ekf, *_ = room
    assert np.allclose(np.diff(seq.stamps_s), ekf.frame_dt_s, rtol=0, atol=1e-9)


def test_an_instantaneous_turn_is_inside_the_search_gate(room):
    """The largest one-frame change of the body rate (a corner's 5.24 deg/frame step) and
    of the world velocity, as one impulse of the model's noise, fall within the search
    ellipse's sigmas; the sequence's rms angular acceleration would not cover the step."""
    _, ekf, search, v, w = room
    gate_sigmas = math.sqrt(search.gate)
    dt = ekf.frame_dt_s
    step_w = np.linalg.norm(np.diff(w, axis=0), axis=1).max()
    step_v = np.linalg.norm(np.diff(v, axis=0), axis=1).max()
    assert math.degrees(step_w) * dt > 5.0  # the turn is there
    assert step_w / (ekf.cv_sigma_alpha_radps2 * dt) <= gate_sigmas
    assert step_v / (ekf.cv_sigma_accel_mps2 * dt) <= gate_sigmas
    alpha_rms = np.sqrt((np.diff(w, axis=0) ** 2).mean(0)).max() / dt
    assert step_w / (alpha_rms * dt) > gate_sigmas


def test_initial_rate_prior_is_the_rms_rate_and_fits_the_search_cap(room):
    """The first frame's ellipse half-side from the initial rate prior (yaw, worst at the
    image's edge) stays under the search's cap; the default 1 rad/s does not even at the
    centre, so no landmark would be searched."""
    seq, ekf, search, _, w = room
    assert abs(ekf.cv_initial_sigma_w_radps - np.sqrt((w ** 2).mean(0)).max()) < RATE_TOL
    fx, cx = seq.K[0, 0], seq.K[0, 2]
    per_rad = math.sqrt(search.gate) * ekf.frame_dt_s * fx
    assert ekf.cv_initial_sigma_w_radps * per_rad * (1 + (cx / fx) ** 2) < search.max_half_extent_px
    assert MonoEkfConfig().cv_initial_sigma_w_radps * per_rad > search.max_half_extent_px


def test_fixed_depth_prior_is_centred_on_the_room(room):
    """depth_prior stays "fixed": its mean 2 min_depth_m (the room's nearest depth, which
    the pipeline passes) is the median depth of the points in view."""
    seq, ekf, *_ = room
    assert ekf.depth_prior == "fixed"
    (W, H), depths = seq.image_size, []
    for i in range(len(seq)):
        uv, z = seq.project(i)
        depths.append(z[(z > seq.config.near_m) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1)
                        & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)])
    median = float(np.median(np.concatenate(depths)))
    assert abs(2 * seq.nearest_depth_m / median - 1) < DEPTH_TOL


@pytest.mark.slow
def test_room_two_laps_from_the_camera_alone_ekf():
    """The run of the file's header (seed 0): the room is followed, ATE within 2 % of the
    path, no warning."""
    config = registry.read_config(CONFIG)
    seq = registry.load_image_sequence("synthetic-images", config=config)
    backend = registry.make_visual_backend(
        "ekf", config=config,
        overrides=vp.backend_overrides("ekf", "none", None,
                                       nearest_depth_m=vp.scene_nearest_depth(seq, config)))
    _, tracker = vp.make_tracker(config, backend)
    result = vp.run(seq, backend, tracker,
                    config=config.section(vp.VisualRunConfig, {"odometry": "none"}))
    m = vp.compute_metrics(result)
    assert m.alignment == "sim3" and m.ate_percent_of_path <= ATE_PERCENT_MAX, m.ate_percent_of_path
    assert not m.warnings, m.warnings
