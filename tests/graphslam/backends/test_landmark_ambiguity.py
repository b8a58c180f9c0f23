"""Unknown association for iSAM2: a pairing that only the pose prior chose is held
(graphslam/backends/planar/landmark_association.py, step 3), and the tail of the
sensor's errors decides which landmarks it tells apart."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import f as f_dist

from filters.association import chi2_quantile, t2_quantile
from graphslam.backends.planar import landmark_association as la
from slamcore.planar.geometry import observe
from slamcore.planar.records import Observation

#: Bearing and range noise of the sightings below: MRCLAM's model at 4 m.
R = np.diag([0.13**2, 0.0083**2])
#: Landmark covariance of a well-mapped landmark, m^2: small beside R.
MAPPED_VAR_M2 = 1e-6


def _joint(heading_sigma_rad: float, n_landmarks: int) -> np.ndarray:
    """Joint marginal of a pose known to 1 cm but for its heading, and of landmarks
    mapped to a millimetre, uncorrelated."""
    P = np.eye(3 + 2 * n_landmarks) * MAPPED_VAR_M2
    P[:3, :3] = np.diag([1e-4, 1e-4, heading_sigma_rad**2])
    return P


def _on_arc(bearings_rad, range_m: float = 4.0) -> np.ndarray:
    """Landmarks (N, 2) at ``range_m`` from the origin, at ``bearings_rad``."""
    b = np.asarray(bearings_rad, dtype=float)
    return range_m * np.stack([np.cos(b), np.sin(b)], axis=1)


def _decide(lms, seen, heading_sigma_rad, dof=math.inf):
    """Decisions for sightings (noise-free, from the origin) of the landmarks ``seen``
    (indices into ``lms``), the believed pose right."""
    assoc = la.LandmarkAssociator(0.999, 3)
    assoc.set_error_dof(dof)
    wTb = np.zeros(3)
    obs = [Observation(0, None, observe(wTb, lms[j]), R) for j in seen]
    ids = np.arange(10, 10 + len(lms))
    return assoc.associate(obs, wTb, ids, lms, _joint(heading_sigma_rad, len(lms)))


@pytest.mark.parametrize("dof", [1.0, 2.5, 5.2, 30.0])
@pytest.mark.parametrize("prob", [0.9, 0.99, 0.999])
def test_the_t_quantile_is_twice_the_f_quantile(prob, dof):
    """d2 / 2 of a bivariate Student-t is F(2, dof); its Gaussian limit is chi-square."""
    assert t2_quantile(prob, dof) == pytest.approx(2.0 * f_dist.ppf(prob, 2, dof), rel=1e-9)
    assert t2_quantile(prob, math.inf) == pytest.approx(chi2_quantile(prob, 2), rel=1e-12)


@pytest.mark.parametrize("bad", [(0.0, 5.0), (1.0, 5.0), (0.5, 0.0), (0.5, -1.0), (0.5, math.nan)])
def test_the_t_quantile_refuses_what_is_no_distribution(bad):
    with pytest.raises(ValueError):
        t2_quantile(*bad)


def test_a_tail_too_wide_for_float64_is_no_gate_and_no_traceback():
    """dof far below 1 puts the 0.999 quantile beyond float64 (SensorField and the
    readers refuse dof < 1; the function itself says inf rather than overflowing)."""
    assert t2_quantile(0.999, 0.001) == math.inf


def test_a_sensor_tail_below_one_dof_is_refused_in_one_line():
    from graphslam.sources.planar.mrclam import MrclamConfig
    from slamcore.errors import ConfigError

    with pytest.raises(ConfigError, match="sighting_error_dof"):
        MrclamConfig(sighting_error_dof=0.001)


def test_a_lone_sighting_that_the_heading_prior_decides_is_held():
    """Two landmarks 0.25 rad apart in bearing (30 bearing sigmas): with the heading
    known to 0.2 rad, one sighting fits either and nothing but the prior picks one, so
    it is held; with the heading known to 0.01 rad it is paired."""
    lms = _on_arc([0.0, 0.25])
    assert [d.kind for d in _decide(lms, [0], 0.2)] == ["held"]
    d = _decide(lms, [0], 0.01)
    assert [(x.kind, x.landmark_id) for x in d] == [("landmark", 10)]


def test_landmarks_the_sensor_cannot_tell_apart_are_paired_anyway():
    """0.1 m apart along the line of sight (under one range sigma): either pairing is as
    good as the sensor can say, so the sighting is paired even under a loose heading."""
    lms = np.array([[4.0, 0.0], [4.1, 0.0]])
    d = _decide(lms, [0], 0.2)
    assert d[0].kind == "landmark"


def test_heavy_tails_make_landmarks_alike_that_a_gaussian_tells_apart():
    """Bearings 0.06 rad apart: d2 = 52 under R, beyond the Gaussian's 0.999 quantile
    (13.8) and within a t(3)'s (297). A Gaussian sensor tells them apart (held); one
    whose errors have a t(3) tail does not (paired)."""
    lms = _on_arc([0.0, 0.06])
    d2 = (0.06 / math.sqrt(R[1, 1])) ** 2
    assert t2_quantile(0.999, math.inf) < d2 < t2_quantile(0.999, 3.0)
    assert _decide(lms, [0], 0.2)[0].kind == "held"
    assert _decide(lms, [0], 0.2, dof=3.0)[0].kind == "landmark"


def test_a_scan_that_fits_two_rotations_of_the_map_is_held_whole():
    """Three landmarks 0.3 rad apart on an arc; the robot sees the first two. Under a
    heading sigma of 0.3 rad the pair fits the map as seen or turned by 0.3 rad (the
    last two): JCBB picks one, both observations are held. Without the third landmark
    only one hypothesis pairs both, and the scan is paired."""
    three = _on_arc([-0.3, 0.0, 0.3])
    assert [d.kind for d in _decide(three, [0, 1], 0.3)] == ["held", "held"]
    two = three[:2]
    d = _decide(two, [0, 1], 0.3)
    assert [(x.kind, x.landmark_id) for x in d] == [("landmark", 10), ("landmark", 11)]


def test_the_joint_test_settles_what_a_lone_sighting_cannot():
    """The lone sighting of the first test is held; seen with a landmark far off to the
    side, whose bearing pins the heading, the same sighting is paired."""
    lms = np.vstack([_on_arc([0.0, 0.25]), [[0.0, 4.0]]])
    assert _decide(lms, [0], 0.2)[0].kind == "held"
    d = _decide(lms, [0, 2], 0.2)
    assert [(x.kind, x.landmark_id) for x in d] == [("landmark", 10), ("landmark", 12)]


def test_a_search_out_of_budget_holds_what_it_could_not_settle(monkeypatch):
    """The hypotheses are searched within MAX_JCBB_NODES tests; a search cut short has
    not shown any pairing to be the only one, so all are held."""
    lms = np.vstack([_on_arc([0.0, 0.25]), [[0.0, 4.0]]])
    monkeypatch.setattr(la, "MAX_JCBB_NODES", 1)
    assert [d.kind for d in _decide(lms, [0, 2], 0.2)] == ["held", "held"]


def test_isam2_reads_the_sensor_tail_from_the_sensor_field():
    from graphslam import registry
    from slamcore.planar.records import SensorField

    backend = registry.make_backend("isam2", overrides={"association": "unknown"})
    backend.initialize(0, np.zeros(3), np.eye(3) * 1e-6)
    backend.set_sensor_field(SensorField(8.0, 1.0, 0.5, 5.2))
    assoc = backend._unknown.associator
    assert assoc.distinct_d2 == pytest.approx(t2_quantile(0.999, 5.2))
    backend.set_sensor_field(None)  # no field known: Gaussian
    assert assoc.distinct_d2 == pytest.approx(chi2_quantile(0.999, 2))
