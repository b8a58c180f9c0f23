"""Sightings whose errors are correlated in time (slamcore.planar.sighting_correlation):
the variance factor against a simulated correlated process, and the bookkeeping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slamcore.errors import ConfigError
from slamcore.planar.records import Observation
from slamcore.planar.sighting_correlation import LastSightings, SightingCorrelation

#: Relative error allowed between the factor and the simulated variance of a mean
#: (2000 seeded runs: the variance estimate itself is known to about 3 %).
FACTOR_REL_TOL = 0.1


@pytest.mark.parametrize("dt_s,tau_s,share", [(0.2, 7.0, 1.0), (1.0, 5.0, 0.5), (3.0, 2.0, 0.9)])
def test_the_factor_is_the_variance_of_a_mean_of_correlated_errors(dt_s, tau_s, share):
    """N sightings dt apart whose error is a share c of an AR(1) process of correlation
    exp(-dt / tau) plus white noise: the mean's variance is the independent one's
    (1 / N) times the factor, for N large against the correlation length."""
    rng = np.random.default_rng(0)
    rho = math.exp(-dt_s / tau_s)
    n, runs = 400, 2000
    ar = np.empty((runs, n))
    ar[:, 0] = rng.standard_normal(runs)
    for k in range(1, n):
        ar[:, k] = rho * ar[:, k - 1] + math.sqrt(1.0 - rho**2) * rng.standard_normal(runs)
    err = math.sqrt(share) * ar + math.sqrt(1.0 - share) * rng.standard_normal((runs, n))
    measured = np.var(err.mean(axis=1)) * n  # 1.0 for independent sightings
    factor, _ = SightingCorrelation(tau_s, share, 0.0).factors(dt_s)
    # the finite-N correction of the AR(1) sum (edge terms), small for n >> 1 / (1 - rho)
    edge = share * 2.0 * rho * (1.0 - rho**n) / (n * (1.0 - rho) ** 2)
    assert measured == pytest.approx(factor - edge, rel=FACTOR_REL_TOL)


def test_first_and_long_apart_sightings_keep_their_covariance():
    model = SightingCorrelation(5.0, 0.9, 0.5)
    assert model.factors(math.inf) == (1.0, 1.0)
    fr, fb = model.factors(200.0)  # 40 time constants
    assert fr == pytest.approx(1.0, abs=1e-15) and fb == pytest.approx(1.0, abs=1e-15)
    fr, fb = model.factors(0.2)
    assert fr > fb > 1.0  # the correlated share of the range is the larger
    assert SightingCorrelation(5.0, 0.0, 0.0).factors(0.2) == (1.0, 1.0)


@pytest.mark.parametrize("bad", [dict(time_constant_s=0.0), dict(time_constant_s=math.nan),
                                 dict(range_share=1.5), dict(bearing_share=-0.1)])
def test_a_bad_model_is_refused(bad):
    with pytest.raises(ConfigError, match="sighting correlation"):
        SightingCorrelation(**{**dict(time_constant_s=5.0, range_share=0.5, bearing_share=0.5), **bad})


def _obs(t, sensor=0):
    return Observation(0, None, np.array([3.0, 0.1]), np.diag([0.01, 1e-4]), stamp_s=t,
                       correlation=SightingCorrelation(5.0, 1.0, 0.5, sensor=sensor))


def test_last_sightings_are_kept_per_landmark_and_per_sensor():
    last = LastSightings()
    R = _obs(0.0).covariance
    np.testing.assert_array_equal(last.covariance(_obs(10.0), 1), R)  # first of landmark 1
    np.testing.assert_array_equal(last.covariance(_obs(10.2), 2), R)  # first of landmark 2
    np.testing.assert_array_equal(last.covariance(_obs(10.3, sensor=1), 1), R)  # other camera
    fr, fb = _obs(0.0).correlation.factors(0.5)
    np.testing.assert_allclose(last.covariance(_obs(10.5), 1), R * np.diag([fr, fb]),
                               rtol=1e-12)
    # a merge keeps the later sighting of the two
    last.merged(1, 2)
    fr, _ = _obs(0.0).correlation.factors(1.0)
    assert last.covariance(_obs(11.5), 1)[0, 0] == pytest.approx(R[0, 0] * fr)


def test_without_time_or_model_a_sighting_is_independent():
    last = LastSightings()
    o = Observation(0, None, np.array([3.0, 0.1]), np.diag([0.01, 1e-4]))
    assert last.observation(o, 1) is o and last.observation(o, 1) is o
    timed = Observation(0, None, o.z, o.covariance, stamp_s=1.0)
    assert last.observation(timed, 1) is timed


def test_the_weight_share_is_one_over_the_geometric_mean_of_the_factors():
    model = SightingCorrelation(time_constant_s=7.32, range_share=0.91, bearing_share=0.53)
    dts = np.array([0.0, 0.05, 0.3, 3.5, 10.0, 60.0, np.inf])
    shares = model.weight_share(dts)
    for dt, share in zip(dts, shares, strict=True):
        fr, fb = model.factors(float(dt))
        assert share == pytest.approx(1.0 / math.sqrt(fr * fb), rel=1e-12)
    assert shares[-1] == 1.0 and np.all((shares > 0) & (shares <= 1.0))
    assert np.all(np.diff(shares) >= 0)  # the longer apart, the more a sighting tells
    assert model.weight_share(-0.3) == pytest.approx(model.weight_share(0.3))  # order-free
