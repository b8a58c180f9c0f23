"""Tests of the synthetic landmark world (seeded; tolerances in physical units)."""

from __future__ import annotations

import numpy as np
import pytest

from slamcore.planar.geometry import compose, observe
from slamcore.config import from_dict, load_section
from slamcore.errors import ConfigError
from graphslam.sources.planar.synthetic import (ODOMETRY_COVARIANCE_FLOOR, SyntheticConfig,
                                         make_synthetic, route_controls,
                                         unicycle_delta)
from slamcore.planar.records import ObservationKind
from slamcore.planar.geometry import wrap_angle

#: How far the last true pose may be from the first (straights round to whole steps).
ROUTE_CLOSURE_TOL_M = 1e-6
#: Relative tolerance on an empirical standard deviation from a few thousand samples.
SIGMA_RTOL = 0.08


@pytest.fixture(scope="module")
def world():
    return make_synthetic(SyntheticConfig())


def _arrays(ds):
    out = [np.array(ds.prior_wTb), np.array(ds.prior_covariance)]
    out += [ds.landmarks_true[i] for i in sorted(ds.landmarks_true)]
    for f in ds.frames:
        out += [np.array(f.wTb_true), np.array([f.stamp_s])]
        if f.odometry is not None:
            out += [f.odometry.delta, f.odometry.covariance]
        for o in f.observations:
            out += [o.z, o.covariance, np.array([o.pose_id, o.landmark_id, o.signature])]
    return out


def test_same_seed_same_bits(world):
    again = make_synthetic(SyntheticConfig(seed=0))
    a, b = _arrays(world), _arrays(again)
    assert len(a) == len(b)
    assert all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b))
    assert [f.true_landmark_ids for f in world.frames] == [f.true_landmark_ids for f in again.frames]


def test_different_seed_differs(world):
    other = make_synthetic(SyntheticConfig(seed=1))
    assert not np.array_equal(world.landmarks_true[0], other.landmarks_true[0])
    assert not np.array_equal(world.frames[1].odometry.delta, other.frames[1].odometry.delta)


def test_dataset_record(world):
    assert world.name == "synthetic" and world.has_timestamps and world.has_ground_truth
    cfg = SyntheticConfig()
    assert len(world.frames) == len(route_controls(cfg)) + 1
    assert world.frames[0].odometry is None
    for k, f in enumerate(world.frames):
        assert f.pose_id == k and f.stamp_s == k * cfg.dt_s
        if k:
            assert (f.odometry.from_id, f.odometry.to_id) == (k - 1, k)
        assert f.true_landmark_ids == tuple(o.landmark_id for o in f.observations)
        assert all(o.kind is ObservationKind.RANGE_BEARING and o.pose_id == k for o in f.observations)
    assert np.array_equal(world.prior_wTb, world.frames[0].wTb_true)
    assert len(world.landmarks_true) == cfg.n_landmarks
    n_obs = sum(len(f.observations) for f in world.frames)
    assert n_obs > len(world.frames)  # ~1.1 per pose at the defaults
    # signatures are per landmark
    sig = {}
    for f in world.frames:
        for o in f.observations:
            assert sig.setdefault(o.landmark_id, o.signature) == o.signature


def test_route_closes_and_revisits_start(world):
    _, gt = world.ground_truth()
    assert np.linalg.norm(gt[-1, :2] - gt[0, :2]) < ROUTE_CLOSURE_TOL_M
    assert abs(wrap_angle(gt[-1, 2] - gt[0, 2])) < 1e-9
    # with 2 laps the start is passed again half way
    n = len(gt) - 1
    assert np.linalg.norm(gt[n // 2, :2] - gt[0, :2]) < ROUTE_CLOSURE_TOL_M
    # a route of a few hundred metres
    length = np.sum(np.linalg.norm(np.diff(gt[:, :2], axis=0), axis=1))
    assert 300.0 < length < 3000.0


def test_observations_in_range_and_fov(world):
    cfg = SyntheticConfig()
    half_fov = np.deg2rad(cfg.fov_deg) / 2
    for f in world.frames:
        for o in f.observations:
            z = observe(f.wTb_true, world.landmarks_true[o.landmark_id])
            assert z[0] <= cfg.sensor_range_m and abs(z[1]) <= half_fov
        # and every landmark in range/fov is observed
        seen = set(f.true_landmark_ids)
        for i, m in world.landmarks_true.items():
            z = observe(f.wTb_true, m)
            if z[0] <= cfg.sensor_range_m and abs(z[1]) <= half_fov:
                assert i in seen


def test_measurement_noise_matches_sigmas(world):
    cfg = SyntheticConfig()
    nu = []
    for f in world.frames:
        for o in f.observations:
            z = observe(f.wTb_true, world.landmarks_true[o.landmark_id])
            nu.append([o.z[0] - z[0], wrap_angle(o.z[1] - z[1])])
    nu = np.array(nu)
    assert len(nu) > 800  # ~870 observations at the defaults
    std = nu.std(axis=0)
    assert std[0] == pytest.approx(cfg.sigma_r_m, rel=SIGMA_RTOL)
    assert np.rad2deg(std[1]) == pytest.approx(cfg.sigma_phi_deg, rel=SIGMA_RTOL)
    assert abs(nu[:, 0].mean()) < 4 * cfg.sigma_r_m / np.sqrt(len(nu))
    cov = next(f.observations[0] for f in world.frames if f.observations).covariance
    assert np.allclose(np.diag(cov), [cfg.sigma_r_m**2, np.deg2rad(cfg.sigma_phi_deg) ** 2])


def test_odometry_noise_matches_covariance(world):
    # whitened odometry errors (true step vs measured) have unit variance along
    # the two noise directions; compare per-axis std with the propagated sigmas
    _, gt = world.ground_truth()
    err, sig = [], []
    for k, f in enumerate(world.frames[1:], start=1):
        c, s = np.cos(gt[k - 1, 2]), np.sin(gt[k - 1, 2])
        d = gt[k, :2] - gt[k - 1, :2]
        true = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], wrap_angle(gt[k, 2] - gt[k - 1, 2])])
        e = f.odometry.delta - true
        e[2] = wrap_angle(e[2])
        err.append(e)
        sig.append(np.sqrt(np.diag(f.odometry.covariance)))
    err, sig = np.array(err), np.array(sig)
    cfg = SyntheticConfig()
    z = err / sig
    assert z[:, 0].std() == pytest.approx(1.0, rel=SIGMA_RTOL)
    assert z[:, 2].std() == pytest.approx(1.0, rel=SIGMA_RTOL)
    # physical units: forward error std = sigma_v dt, heading error std = sigma_w dt
    assert err[:, 0].std() == pytest.approx(cfg.sigma_v_mps * cfg.dt_s, rel=SIGMA_RTOL)
    assert np.rad2deg(err[:, 2].std()) == pytest.approx(cfg.sigma_w_degps * cfg.dt_s, rel=SIGMA_RTOL)


def test_unicycle_jacobian_numerical():
    for v, w in [(1.0, 0.0), (1.0, 1e-6), (1.3, 0.157), (0.7, -0.9)]:
        _, J = unicycle_delta(v, w, 1.0)
        h = 1e-6
        num = np.stack([(unicycle_delta(v + h, w, 1.0)[0] - unicycle_delta(v - h, w, 1.0)[0]) / (2 * h),
                        (unicycle_delta(v, w + h, 1.0)[0] - unicycle_delta(v, w - h, 1.0)[0]) / (2 * h)],
                       axis=-1)
        assert np.allclose(J, num, atol=1e-7)


def test_odometry_covariance_floor(world):
    cov = world.frames[5].odometry.covariance
    assert np.linalg.eigvalsh(cov).min() >= 0.5 * np.linalg.eigvalsh(ODOMETRY_COVARIANCE_FLOOR).min()


def test_dead_reckoning_drifts(world):
    from graphslam.evaluation import planar as metrics
    from graphslam.pipelines.planar import dead_reckoning

    ids, odo = dead_reckoning(world)
    gt_ids, gt = world.ground_truth()
    ate = metrics.ate(ids, odo, gt_ids, gt)["rmse_m"]
    assert ate > 1.0  # metres: visible drift for the demo
    # with noise-free odometry dead reckoning equals the truth
    cfg = SyntheticConfig()
    true_delta, _ = unicycle_delta(*route_controls(cfg).T, cfg.dt_s)
    pose = gt[0]
    for d in true_delta:
        pose = compose(pose, d)
    assert np.linalg.norm(pose[:2] - gt[-1, :2]) < 1e-6


def test_config_loads_from_file(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[synthetic]\nseed = 7\nn_landmarks = 50\nlaps = 1\n")
    cfg = load_section(SyntheticConfig, p, {"seed": None})
    assert (cfg.seed, cfg.n_landmarks, cfg.laps) == (7, 50, 1)
    assert cfg.sigma_v_mps == 0.05 and cfg.sigma_w_degps == 0.1
    assert cfg.sigma_r_m == 0.2 and cfg.sigma_phi_deg == 10.0


@pytest.mark.parametrize("changes", [
    {"seed": -1}, {"n_landmarks": 0}, {"laps": 0}, {"speed_mps": 0.0}, {"dt_s": -1.0},
    {"sensor_range_m": 0.0}, {"fov_deg": 0.0}, {"fov_deg": 400.0}, {"sigma_v_mps": 0.0},
    {"sigma_w_degps": -0.1}, {"sigma_r_m": float("nan")}, {"sigma_phi_deg": 0.0},
    {"corner_radius_m": 50.0}, {"world_margin_m": -1.0}, {"laps": 1.5},
])
def test_config_validation(changes):
    with pytest.raises(ConfigError):
        SyntheticConfig(**changes)
    with pytest.raises(ConfigError):
        from_dict(SyntheticConfig, changes)


def test_small_world_is_fast():
    ds = make_synthetic(SyntheticConfig(laps=1, n_landmarks=30, route_length_m=40.0,
                                        route_width_m=30.0, corner_radius_m=5.0))
    _, gt = ds.ground_truth()
    assert np.linalg.norm(gt[-1, :2]) < ROUTE_CLOSURE_TOL_M
