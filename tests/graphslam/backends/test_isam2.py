"""iSAM2 back end against batch Levenberg-Marquardt on small problems."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from slamcore.planar.geometry import observe_jacobians
from graphslam.backends import gtsam_convert as conv
from graphslam.pipelines import planar as pipeline
from slamcore.errors import ConfigError, MeasurementError
from graphslam.backends.planar.isam2 import Isam2Backend
from graphslam.backends.planar.isam2_config import Isam2Config
from slamcore.planar.records import Estimate, Observation, Odometry
from tests.worlds import assert_poses_close, square_world

#: Incremental with default relinearisation (threshold 0.1) vs batch optimum:
#: variables whose delta stays under the threshold keep a stale linearisation.
INCREMENTAL_TOL = 0.02
#: Incremental relinearising every variable at every update vs batch optimum.
FULL_RELIN_TOL = 1e-4
#: Polished vs batch optimum: same graph, LM from two starts, each stopping at
#: gtsam's default relative error decrease of 1e-5 (metres / radians).
POLISHED_TOL = 2e-5


def batch_lm(ds):
    graph = conv.dataset_graph(ds)
    ids, _ = ds.ground_truth()
    _, odo = pipeline.dead_reckoning(ds)
    init = conv.estimate_values(
        Estimate(
            ids,
            odo,
            np.array(sorted(ds.landmarks_true)),
            np.array([ds.landmarks_true[j] for j in sorted(ds.landmarks_true)]),
        )
    )
    return graph, gtsam.LevenbergMarquardtOptimizer(graph, init).optimize()


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_batch_lm(seed):
    """The same Gaussian graph as gtsam's batch LM: no robust kernel on the sightings."""
    ds = square_world(seed=seed)
    graph, optimum = batch_lm(ds)
    gauss = {"observation_kernel": "none"}
    inc = pipeline.run(ds, Isam2Backend(Isam2Config(polish=False, **gauss))).estimate
    full = pipeline.run(
        ds, Isam2Backend(Isam2Config(polish=False, relinearize_threshold=1e-9, relinearize_skip=1, **gauss))
    ).estimate
    pol_backend = Isam2Backend(Isam2Config(polish=True, **gauss))
    pol = pipeline.run(ds, pol_backend).estimate
    ref = conv.values_to_estimate(optimum, inc.pose_ids, inc.landmark_ids)
    assert_poses_close(inc.wTb, ref.wTb, INCREMENTAL_TOL)
    assert_poses_close(full.wTb, ref.wTb, FULL_RELIN_TOL)
    assert_poses_close(pol.wTb, ref.wTb, POLISHED_TOL)
    np.testing.assert_allclose(pol.landmarks_w, ref.landmarks_w, atol=POLISHED_TOL)
    # the graph error reported for any back end equals the back end's own
    assert conv.graph_cost(ds, pol)[0] == pytest.approx(pol_backend.error(), rel=1e-9)
    assert pol_backend.error() == pytest.approx(graph.error(optimum), rel=1e-6)


def test_incremental_cost_uses_one_update_per_frame(monkeypatch):
    ds = square_world(seed=0)
    backend = Isam2Backend(Isam2Config(polish=False))
    calls = []
    monkeypatch.setattr(backend, "_isam", _Spy(backend._isam, calls))
    pipeline.run(ds, backend)
    assert len(calls) == len(ds.frames)


class _Spy:
    def __init__(self, inner, calls):
        self._inner, self._calls = inner, calls

    def update(self, *args):
        self._calls.append(args[0].size())
        return self._inner.update(*args)

    def __getattr__(self, name):
        return getattr(self._inner, name)


def test_prediction_jacobian_matches_filter_model():
    """gtsam's H is in the body-frame tangent space: H_body = H_world @ blockdiag(R, 1)."""
    ds = square_world(seed=4, loop_closure=False)
    backend = Isam2Backend(Isam2Config(polish=False))
    pipeline.run(ds.truncated(12), backend)
    est = backend.estimate(with_covariances=True)
    x = est.current_pose
    for pred in backend.predict_observations(est.landmark_ids):
        i = list(est.landmark_ids).index(pred.landmark_id)
        m = est.landmarks_w[i]
        H_x, H_m = observe_jacobians(x, m)
        c, s = np.cos(x[2]), np.sin(x[2])
        T = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])  # body tangent -> world increments
        H = np.hstack([H_x @ T, H_m])
        marg = gtsam.Marginals(backend.factor_graph(), conv.estimate_values(backend.estimate()))
        from gtsam.symbol_shorthand import L, X

        P = marg.jointMarginalCovariance(
            gtsam.KeyVector([X(int(est.pose_ids[-1])), L(int(pred.landmark_id))])
        ).fullMatrix()
        R = next(o.covariance for f in ds.frames for o in f.observations)
        np.testing.assert_allclose(pred.innovation_covariance, H @ P @ H.T + R, rtol=1e-6, atol=1e-12)


def test_config_validation():
    with pytest.raises(ConfigError):
        Isam2Config(relinearize_threshold=0)
    with pytest.raises(ConfigError):
        Isam2Config(relinearize_skip=0)


def test_ids_a_gtsam_symbol_cannot_hold_are_refused_by_name():
    # the records take any int64 (the filters use them); gtsam's X()/L() raised bare
    # TypeError (negative) and ValueError (2**56 and beyond)
    with pytest.raises(MeasurementError, match="pose -1"):
        Isam2Backend().initialize(-1, np.zeros(3), np.eye(3) * 1e-6)
    b = Isam2Backend()
    b.initialize(0, np.zeros(3), np.eye(3) * 1e-6)
    with pytest.raises(MeasurementError, match=f"pose {2**56}"):
        b.predict(Odometry(0, 2**56, [1.0, 0, 0], np.eye(3) * 0.01), 2**56)
    for lid in (-5, 2**60):
        with pytest.raises(MeasurementError, match=f"landmark {lid}"):
            b.update([Observation(0, lid, [2.0, 0.1], np.eye(2) * 0.01)])


#: iSAM2's marginal against the EKF's covariance on the same odometry-only chain: both
#: first order at the same estimate, so they agree to round-off (relative).
COVARIANCE_RTOL = 1e-6


def test_pose_covariances_are_in_the_world_frame_as_the_filters_hold_them():
    """gtsam's Pose2 marginals are in the pose's body frame; the contract's (the EKF's, the
    NEES's) are world ``[x, y, theta]``. An odometry-only chain that turns, from a prior
    long in one world direction: the two back ends agree at every step. Read as world
    ones, gtsam's marginals pointed along the body's axes (MRCLAM robot 1 with ids: mean
    pose NEES 17.7, 4.3 since)."""
    from graphslam import registry

    P0 = np.array([[0.04, 0.015, 0.002], [0.015, 0.01, -0.001], [0.002, -0.001, 0.003]])
    wTb0 = np.array([1.0, -2.0, 0.7])
    isam = Isam2Backend(Isam2Config(polish=False))
    ekf = registry.make_backend("ekf")
    for b in (isam, ekf):
        b.initialize(0, wTb0, P0)
    np.testing.assert_allclose(isam.current_pose_covariance(), P0, rtol=COVARIANCE_RTOL)
    Q = np.diag([0.02**2, 0.02**2, 0.01**2])  # round in x, y: the noise's frame does not matter
    for k in range(1, 12):
        step = Odometry(k - 1, k, np.array([0.5, 0.1, 0.4 if k % 3 else -0.9]), Q)
        for b in (isam, ekf):
            b.predict(step, k)
            b.update([])
        np.testing.assert_allclose(isam.current_pose_covariance(), ekf.current_pose_covariance(), rtol=COVARIANCE_RTOL)
    est = isam.estimate(with_covariances=True)
    np.testing.assert_allclose(est.pose_covariances, ekf.estimate(with_covariances=True).pose_covariances, rtol=COVARIANCE_RTOL)


def test_covariance_frame_round_trip():
    P = np.array([[0.04, 0.015, 0.002], [0.015, 0.01, -0.001], [0.002, -0.001, 0.003]])
    for theta in (0.0, 0.7, -2.5, np.pi):
        np.testing.assert_allclose(conv.pose2_covariance_from_gtsam(theta, conv.pose2_covariance_to_gtsam(theta, P)), P, atol=1e-15)
    # the heading's variance and a round x-y block do not depend on the frame
    round_ = np.diag([0.01, 0.01, 0.003])
    assert conv.pose2_covariance_to_gtsam(1.1, round_) is round_
    assert conv.pose2_covariance_from_gtsam(1.1, P)[2, 2] == P[2, 2]
