"""The back-end contract (DESIGN.md), written once and run on every back end."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam import registry
from graphslam.pipelines import planar as pipeline
from slamcore.planar.backend import Backend
from dataclasses import replace

from slamcore.errors import GraphSlamError, MeasurementError, UnsupportedError
from slamcore.planar.records import LoopClosure, Observation, Odometry
from tests.worlds import assert_poses_close, square_world

#: Noise-free data must be reproduced to this by deterministic back ends, m / rad.
EXACT_TOL = 1e-6
#: Particle filters sample their motion from the odometry covariance even when
#: the data are noise-free, so they reproduce the truth only to within the
#: spread of the cloud (square world: sigma 0.05 m per step), m / rad.
PARTICLE_EXACT_TOL = 0.15
#: Noisy square world: pose error bound after the run, metres.
NOISY_POSE_TOL_M = 0.3

#: name -> tolerance of the noise-free reproduction test; every back end of the
#: registry must appear here, so that a new one cannot skip the contract.
EXACT = {
    "isam2": EXACT_TOL,
    "ekf": EXACT_TOL,
    "fastslam1": PARTICLE_EXACT_TOL,
    "fastslam2": PARTICLE_EXACT_TOL,
}


def test_every_registered_backend_runs_the_contract():
    assert set(EXACT) == set(registry.BACKENDS)


@pytest.fixture(params=sorted(EXACT))
def make_backend(request):
    def make():
        return registry.make_backend(request.param)

    make.exact_tol = EXACT[request.param]
    return make


def test_is_a_backend(make_backend):
    b = make_backend()
    assert isinstance(b, Backend)
    assert isinstance(b.name, str) and b.name


def test_noise_free_run_reproduces_truth(make_backend):
    ds = square_world(noise=False, loop_closure=False)
    res = pipeline.run(ds, make_backend())
    ids, truth = ds.ground_truth()
    np.testing.assert_array_equal(res.estimate.pose_ids, ids)
    tol = make_backend.exact_tol
    assert_poses_close(res.estimate.wTb, truth, tol)
    for lid, m in zip(res.estimate.landmark_ids, res.estimate.landmarks_w):
        np.testing.assert_allclose(m, ds.landmarks_true[int(lid)], atol=tol)


def test_noisy_run_is_accurate_and_repeatable(make_backend):
    ds = square_world(seed=3, loop_closure=False)
    a = pipeline.run(ds, make_backend()).estimate
    b = pipeline.run(ds, make_backend()).estimate
    np.testing.assert_array_equal(a.wTb, b.wTb)  # same inputs, same bits
    err = np.linalg.norm(a.wTb[:, :2] - ds.ground_truth()[1][:, :2], axis=1)
    assert err.max() < NOISY_POSE_TOL_M


def test_reversed_odometry_edges(make_backend):
    fwd = square_world(noise=False, loop_closure=False)
    rev = square_world(noise=False, loop_closure=False, reverse_every=3)
    a = pipeline.run(fwd, make_backend()).estimate
    b = pipeline.run(rev, make_backend()).estimate
    assert_poses_close(a.wTb, b.wTb, make_backend.exact_tol)


def test_odometry_not_touching_known_pose_is_refused(make_backend):
    b = make_backend()
    b.initialize(0, np.zeros(3), np.eye(3) * 1e-6)
    with pytest.raises(GraphSlamError):
        b.predict(Odometry(5, 6, np.array([1.0, 0, 0]), np.eye(3) * 0.01), 6)


def test_associations_one_per_observation(make_backend):
    ds = square_world(noise=False)
    b = make_backend()
    b.initialize(0, ds.prior_wTb, ds.prior_covariance)
    b.update(ds.frames[0].observations)
    assert b.associations() == [o.landmark_id for o in ds.frames[0].observations]


def test_predicted_observations(make_backend):
    ds = square_world(seed=1, loop_closure=False)
    b = make_backend()
    pipeline.run(ds.truncated(15), b)
    est = b.estimate()
    preds = b.predict_observations(list(est.landmark_ids) + [999])  # 999 unknown: skipped
    assert {p.landmark_id for p in preds} == set(int(i) for i in est.landmark_ids)
    from slamcore.planar.geometry import observe

    for p in preds:
        m = est.landmarks_w[list(est.landmark_ids).index(p.landmark_id)]
        np.testing.assert_allclose(p.z, observe(est.current_pose, m), atol=1e-6)
        S = p.innovation_covariance
        np.testing.assert_allclose(S, S.T, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(S) > 0)


def test_estimate_covariances(make_backend):
    ds = square_world(seed=2, loop_closure=False)
    est = pipeline.run(ds, make_backend(), with_covariances=True).estimate
    n, m = len(est.pose_ids), len(est.landmark_ids)
    assert est.pose_covariances.shape == (n, 3, 3)
    assert est.landmark_covariances.shape == (m, 2, 2)
    assert np.all(np.linalg.eigvalsh(est.landmark_covariances) > 0)


def test_loop_closure_used_or_refused_plainly(make_backend):
    b = make_backend()
    b.initialize(0, np.zeros(3), np.eye(3) * 1e-6)
    b.predict(Odometry(0, 1, np.array([1.0, 0, 0]), np.eye(3) * 0.01), 1)
    lc = LoopClosure(0, 1, np.array([1.0, 0, 0]), np.eye(3) * 0.01)
    if b.supports_loop_closures:
        b.add_loop_closure(lc)
        assert b.estimate().wTb.shape == (2, 3)
    else:
        with pytest.raises(UnsupportedError):
            b.add_loop_closure(lc)


def test_loop_closure_reduces_error_when_supported(make_backend):
    if not make_backend().supports_loop_closures:
        pytest.skip("back end closes loops by re-observing landmarks")
    kw = dict(seed=5, sensor_range_m=0.5)  # no landmarks in range: odometry + closure only
    with_lc = pipeline.run(square_world(loop_closure=True, **kw), make_backend()).estimate
    without = pipeline.run(square_world(loop_closure=False, **kw), make_backend()).estimate
    truth = square_world(**kw).ground_truth()[1]
    e_with = np.linalg.norm(with_lc.wTb[-1, :2] - truth[-1, :2])
    e_without = np.linalg.norm(without.wTb[-1, :2] - truth[-1, :2])
    assert e_with < e_without


def test_calls_before_initialize_are_refused(make_backend):
    b = make_backend()
    for call in (b.estimate, b.finalize, b.current_pose):
        with pytest.raises(GraphSlamError, match=r"initialize\(\) must"):
            call()


def test_update_takes_a_list_of_observations(make_backend):
    b = make_backend()
    b.initialize(0, np.zeros(3), np.eye(3) * 1e-6)
    with pytest.raises(MeasurementError, match="update takes a list of observations"):
        b.update(Observation(0, 1, [2.0, 0.1], np.eye(2) * 0.01))


#: what initialize() refuses, all back ends alike (filters.planar_inputs.initial_pose)
BAD_PRIORS = {
    "pose of 4 values": (0, [1.0, 2.0, 0.1, 9.0], np.eye(3) * 1e-6),
    "NaN in the pose": (0, [np.nan, 0.0, 0.0], np.eye(3) * 1e-6),
    "2x2 covariance": (0, np.zeros(3), np.eye(2) * 1e-6),
    "indefinite covariance": (0, np.zeros(3), np.diag([1e-6, -1e-6, 1e-6])),
    "fractional pose id": (2.7, np.zeros(3), np.eye(3) * 1e-6),
    "pose id as text": ("5", np.zeros(3), np.eye(3) * 1e-6),
}


@pytest.mark.parametrize("bad", sorted(BAD_PRIORS))
def test_initialize_refuses_a_bad_prior(make_backend, bad):
    with pytest.raises(MeasurementError, match="initial pose"):
        make_backend().initialize(*BAD_PRIORS[bad])


def test_run_refuses_a_dataset_with_a_bad_prior(make_backend):
    ds = square_world(noise=False, loop_closure=False).truncated(3)
    with pytest.raises(MeasurementError, match="covariance is not positive definite"):
        pipeline.run(replace(ds, prior_covariance=-np.eye(3)), make_backend())


@pytest.mark.parametrize("association", ["known", "unknown"])
def test_end_of_run_reports_have_the_contracts_types(make_backend, association):
    """What the pipeline reads of a finished run, through the contract only (the
    re-association was read with getattr, so a back end could drop it silently)."""
    ds = square_world(seed=2, loop_closure=False)
    if association == "unknown":
        ds = replace(ds, frames=[replace(f, observations=[replace(o, landmark_id=None) for o in f.observations])
                                 for f in ds.frames])
    name = make_backend().name  # the registry key
    res = pipeline.run(ds, registry.make_backend(name, overrides={"association": association}))
    b_re = res.reassociation
    assert b_re is None or (isinstance(b_re[0], int) and b_re[0] >= 0 and isinstance(b_re[1], bool))
    assert res.landmarks_pruned >= 0
