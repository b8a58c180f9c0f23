"""Step 7 of benchmarks/calibrate_mrclam.py: what the sightings of one frame share.

Seeded sightings with a known bearing error common to each frame and an own error per
sighting: the step must return the common one, count only pairs of different landmarks
in one frame, and leave the per-landmark median out.
"""

from __future__ import annotations

import numpy as np

from graphslam.sources.planar.mrclam import MrclamConfig
from tests.benchmarks import load_benchmark

#: The common bearing error drawn per frame, rad (Dataset 6 measures 0.0070).
SHARED_SIGMA_RAD = 0.007
#: Each sighting's own bearing error, rad.
OWN_SIGMA_RAD = 0.004
#: Tolerance on the recovered common sigma, rad: about four standard errors at the
#: pair count below.
SIGMA_TOL_RAD = 0.0008


def _sightings(seed: int, frames: int = 2000, shared: float = SHARED_SIGMA_RAD) -> dict:
    rng = np.random.default_rng(seed)
    time = np.repeat(np.arange(frames) * 0.2, 3)
    subject = np.tile([6, 7, 8], frames)
    z = np.column_stack([rng.uniform(1.0, 4.0, time.size), rng.uniform(-0.5, 0.5, time.size)])
    bearing = np.repeat(rng.normal(0.0, shared, frames), 3) + rng.normal(0.0, OWN_SIGMA_RAD, time.size)
    bias = {6: 0.02, 7: -0.03, 8: 0.0}  # a per-landmark offset the median must remove
    bearing += np.array([bias[s] for s in subject])
    residual = np.column_stack([rng.normal(0.0, 0.01, time.size), bearing])
    return {"time": time, "subject": subject, "z": z, "residual": residual}


def test_the_bearing_error_a_frame_shares_is_recovered():
    step = load_benchmark("calibrate_mrclam").shared_scan_error
    out = step([_sightings(0)], MrclamConfig())
    assert out["pairs"] == 3 * 2000
    assert abs(out["bearing_shared_sigma_rad"] - SHARED_SIGMA_RAD) < SIGMA_TOL_RAD
    assert out["bearing_correlation"] > 0.5
    assert abs(out["range_correlation"]) < 0.1


def test_nothing_shared_reads_as_nothing_and_one_landmark_twice_is_no_pair():
    step = load_benchmark("calibrate_mrclam").shared_scan_error
    assert step([_sightings(1, shared=0.0)], MrclamConfig())["bearing_shared_sigma_rad"] < SIGMA_TOL_RAD
    same = _sightings(2)
    same["subject"] = np.full_like(same["subject"], 6)
    assert step([same], MrclamConfig())["pairs"] == 0
