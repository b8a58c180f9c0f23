"""FastSLAM with unknown ids: the new-landmark gate from the sensor's error tail
(``[fastslam] new_landmark_mahalanobis_sq`` unset, filters/fastslam_config.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from filters.association import chi2_quantile, t2_quantile
from filters.fastslam import FastSlam
from filters.fastslam_config import FastSlamConfig
from slamcore.planar import geometry as models
from slamcore.planar.records import Observation, Odometry, SensorField

#: Sighting noise: 0.1 m in range, 0.01 rad in bearing.
R = np.diag([0.1**2, 0.01**2])
LANDMARK = np.array([4.0, 0.0])
#: A second sighting 0.55 m further in range: d2 = 30 under R (plus the landmark's
#: own small uncertainty), beyond a Gaussian's 0.999 gate, inside a t(5.1)'s.
FAR_RANGE_M = 0.55


def _landmarks_after_two_sightings(config: FastSlamConfig, field: SensorField | None) -> int:
    slam = FastSlam(config)
    slam.initialize(0, np.zeros(3), np.eye(3) * 1e-10)
    slam.set_sensor_field(field)
    z = models.observe(np.zeros(3), LANDMARK)
    slam.update([Observation(0, None, z, R)])
    slam.predict(Odometry(0, 1, np.zeros(3), np.eye(3) * 1e-10), 1)
    slam.update([Observation(1, None, z + np.array([FAR_RANGE_M, 0.0]), R)])
    return len(slam.estimate().landmark_ids)


@pytest.mark.parametrize("version", [1, 2])
def test_a_heavy_tailed_sensor_pairs_what_a_gaussian_maps_anew(version):
    d2 = FAR_RANGE_M**2 / R[0, 0]
    assert chi2_quantile(0.999, 2) < d2 < t2_quantile(0.999, 5.1)
    unknown = FastSlamConfig(version=version, association="unknown", n_particles=20)
    assert _landmarks_after_two_sightings(unknown, SensorField(8.0, 1.0, 0.5)) == 2
    assert _landmarks_after_two_sightings(unknown, None) == 2
    assert _landmarks_after_two_sightings(unknown, SensorField(8.0, 1.0, 0.5, 5.1)) == 1
    # a set gate wins over the sensor's tail
    fixed = FastSlamConfig(version=version, association="unknown", n_particles=20,
                           new_landmark_mahalanobis_sq=13.8155)
    assert _landmarks_after_two_sightings(fixed, SensorField(8.0, 1.0, 0.5, 5.1)) == 2


def test_the_gate_is_the_sensors_quantile_unless_set():
    slam = FastSlam(FastSlamConfig(association="unknown"))
    gate = slam.particles.new_gate_d2
    assert gate == pytest.approx(chi2_quantile(0.999, 2))
    slam.set_sensor_field(SensorField(8.0, 1.0, 0.5, 5.1))
    assert slam.particles.new_gate_d2 == pytest.approx(t2_quantile(0.999, 5.1))
    assert slam.particles.new_gate_d2 == pytest.approx(71.47, abs=0.01)
    slam.set_sensor_field(SensorField(8.0, 1.0, 0.5, math.inf))
    assert slam.particles.new_gate_d2 == pytest.approx(gate)
