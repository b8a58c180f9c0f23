"""EKF-SLAM with unknown ids holds a sighting whose pairing only the pose prior chose
(filters/ekf_slam_association.py, ``distinct_d2``; the rule iSAM2 follows,
tests/graphslam/backends/test_landmark_ambiguity.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from filters.association import chi2_quantile, confirming_sightings, t2_quantile
from filters.ekf_slam import EkfSlam
from filters.ekf_slam_association import associate_scan
from filters.ekf_slam_config import EkfSlamConfig
from slamcore.planar import geometry as models
from slamcore.planar.records import Observation, Odometry, SensorField

#: MRCLAM's sighting noise at 4 m: range 0.13 m, bearing 0.0083 rad.
R = np.diag([0.13**2, 0.0083**2])
GATE = chi2_quantile(0.999, 2)
#: Two landmarks 4 m ahead, 0.25 rad apart in bearing (30 bearing sigmas).
LANDMARKS = 4.0 * np.array([[1.0, 0.0], [math.cos(0.25), math.sin(0.25)]])


def _state(heading_sigma_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Robot at the origin known to 1 cm but for its heading; both landmarks mapped
    to a millimetre, uncorrelated."""
    x = np.concatenate([np.zeros(3), LANDMARKS.ravel()])
    P = np.eye(7) * 1e-6
    P[:3, :3] = np.diag([1e-4, 1e-4, heading_sigma_rad**2])
    return x, P


def _associate(heading_sigma_rad: float, distinct_d2: float | None):
    x, P = _state(heading_sigma_rad)
    Z = models.observe(np.zeros(3), LANDMARKS[:1])
    Pmm = np.stack([P[k : k + 2, k : k + 2] for k in (3, 5)])
    return associate_scan(x, P, Pmm, Z, R[None], gate=GATE, chi2_prob=0.999, max_candidates=3,
                          max_nodes=2000, likelihood=(0.015, 0.9), distinct_d2=distinct_d2)


def test_a_lone_sighting_the_heading_prior_decides_is_held():
    held = _associate(0.2, GATE)
    assert held.hypothesis == [None] and held.held == [True]
    paired = _associate(0.2, None)  # without the test: the nearest under the prior
    assert paired.hypothesis == [0] and paired.held == [False]
    sure = _associate(0.01, GATE)  # heading known: the sensor decides
    assert sure.hypothesis == [0] and sure.held == [False]


def test_a_wide_error_tail_pairs_landmarks_a_gaussian_would_tell_apart():
    """0.25 rad is 30 bearing sigmas (d2 = 907): distinct for a Gaussian sensor (0.999
    quantile 13.8), not for one whose errors have a t(1.5) tail (14 998): paired."""
    assert _associate(0.2, t2_quantile(0.999, 1.5)).held == [False]


def test_the_filter_neither_updates_nor_maps_a_held_sighting():
    """Through the filter: the sighting is reported unpaired, no landmark is added, and
    the state is the prediction's; a sensor field with a wide tail lets it pair."""
    def run(field):
        # landmarks at their first sighting whatever the tail: the hold alone is tested
        ekf = EkfSlam(EkfSlamConfig(association="unknown", provisional_sightings=1))
        ekf.initialize(0, np.zeros(3), np.diag([1e-4, 1e-4, 1e-8]))
        ekf.set_sensor_field(field)
        for lm in LANDMARKS:  # map both from the known pose
            ekf.update([Observation(0, None, models.observe(np.zeros(3), lm), R * 1e-4)])
        ekf.predict(Odometry(0, 1, np.zeros(3), np.diag([1e-8, 1e-8, 0.2**2])), 1)
        before = ekf.state_vector().copy()
        ekf.update([Observation(1, None, models.observe(np.zeros(3), LANDMARKS[0]), R)])
        return ekf, before

    ekf, before = run(SensorField(8.0, 1.0, 0.5))
    assert ekf.num_landmarks == 2
    assert ekf.associations() == [None]
    np.testing.assert_array_equal(ekf.state_vector(), before)
    ekf, _ = run(SensorField(8.0, 1.0, 0.5, 1.5))
    assert ekf.num_landmarks == 2 and ekf.associations() == [ekf.landmark_ids()[0]]


@pytest.mark.parametrize("heading_sigma_rad", [0.2, 0.01])
def test_without_a_distinct_gate_the_search_is_the_old_one(heading_sigma_rad):
    """``distinct_d2=None`` gives JCBB's closest candidates only, as before the rule."""
    res = _associate(heading_sigma_rad, None)
    assert res.held == [False]
    assert res.hypothesis == [0]  # the nearest under the prior, as JCBB alone pairs it


# ------------------------------------------------ confirming a new landmark (provisional list)

@pytest.mark.parametrize("dof", [1.0, 2.0, 3.0, 5.1, 10.0, 100.0])
@pytest.mark.parametrize("prob", [0.99, 0.999])
def test_confirming_sightings_is_the_fewest_that_make_outliers_as_rare_as_the_gate(prob, dof):
    """q^n <= 1 - p < q^(n - 1), q the t error's chance to fall beyond the Gaussian gate
    (from its distribution, 1 - (1 + x / dof)^(-dof / 2))."""
    n = confirming_sightings(prob, dof)
    q = (1.0 + chi2_quantile(prob, 2) / dof) ** (-dof / 2.0)
    assert q**n <= 1.0 - prob < q ** (n - 1)


def test_confirming_sightings_for_a_gaussian_and_for_mrclams_camera():
    assert confirming_sightings(0.999, math.inf) == 1
    assert confirming_sightings(0.999, 5.1) == 3  # as iSAM2's confirm_sightings
    with pytest.raises(ValueError):
        confirming_sightings(1.0, 5.0)
    with pytest.raises(ValueError):
        confirming_sightings(0.999, 0.0)


def _first_sightings(config: EkfSlamConfig, field: SensorField | None) -> list[int]:
    """Landmarks in the map after each of three sightings of one landmark."""
    ekf = EkfSlam(config)
    ekf.initialize(0, np.zeros(3), np.eye(3) * 1e-8)
    ekf.set_sensor_field(field)
    out = []
    for k in range(3):
        if k:
            ekf.predict(Odometry(k - 1, k, np.zeros(3), np.eye(3) * 1e-8), k)
        ekf.update([Observation(k, 7, models.observe(np.zeros(3), LANDMARKS[0]), R)])
        out.append(ekf.num_landmarks)
    return out


def test_a_heavy_tailed_sensor_confirms_a_new_landmark_on_its_third_sighting():
    unknown = EkfSlamConfig(association="unknown")
    assert _first_sightings(unknown, SensorField(8.0, 1.0, 0.5, 5.1)) == [0, 0, 1]
    assert _first_sightings(unknown, SensorField(8.0, 1.0, 0.5)) == [1, 1, 1]  # Gaussian
    assert _first_sightings(unknown, None) == [1, 1, 1]
    # a set count wins; known ids enter at their first sighting, whatever the sensor
    fixed = EkfSlamConfig(association="unknown", provisional_sightings=2)
    assert _first_sightings(fixed, SensorField(8.0, 1.0, 0.5, 5.1)) == [0, 1, 1]
    known = EkfSlamConfig(association="known")
    assert _first_sightings(known, SensorField(8.0, 1.0, 0.5, 5.1)) == [1, 1, 1]
