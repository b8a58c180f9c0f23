"""Tests of graphslam.evaluation.planar (numpy only)."""

from __future__ import annotations

import numpy as np
import pytest

from graphslam.evaluation import planar as metrics
from slamcore.planar.geometry import between
from slamcore.errors import GraphSlamError

#: Alignment / ATE exactness on noise-free data, metres.
EXACT_TOL_M = 1e-9
#: Tolerance on an ATE computed from a few thousand noisy samples, relative.
NOISY_RTOL = 0.05


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _traj(rng, n=200):
    th = np.cumsum(rng.normal(0, 0.1, n))
    xy = np.cumsum(np.stack([np.cos(th), np.sin(th)], axis=1), axis=0)
    return np.column_stack([xy, metrics.wrap_angle(th)])


def _transform(wTb, R, t):
    out = wTb.copy()
    out[:, :2] = wTb[:, :2] @ R.T + t
    out[:, 2] = metrics.wrap_angle(wTb[:, 2] + np.arctan2(R[1, 0], R[0, 0]))
    return out


def test_align_recovers_rigid_transform():
    rng = np.random.default_rng(0)
    for _ in range(5):
        src = rng.uniform(-50, 50, (30, 2))
        R, t = _rot(rng.uniform(-np.pi, np.pi)), rng.uniform(-100, 100, 2)
        R_est, t_est = metrics.align_se2(src, src @ R.T + t)
        assert np.allclose(R_est, R, atol=1e-12)
        assert np.max(np.abs(t_est - t)) < EXACT_TOL_M
        assert np.linalg.det(R_est) == pytest.approx(1.0)


def test_align_never_reflects():
    rng = np.random.default_rng(1)
    src = rng.uniform(-10, 10, (20, 2))
    R, _ = metrics.align_se2(src, src * np.array([1.0, -1.0]))  # a mirror image
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_ate_of_transformed_copy_is_zero():
    rng = np.random.default_rng(2)
    gt = _traj(rng)
    est = _transform(gt, _rot(0.7), np.array([5.0, -3.0]))
    ids = np.arange(len(gt))
    r = metrics.ate(ids, est, ids, gt)
    assert r["rmse_m"] < EXACT_TOL_M and r["max_m"] < EXACT_TOL_M and r["n"] == len(gt)
    assert metrics.ate(ids, est, ids, gt, align=False)["rmse_m"] > 1.0


def test_ate_with_known_noise():
    rng = np.random.default_rng(3)
    gt = _traj(rng, 5000)
    sigma = 0.3
    est = gt.copy()
    est[:, :2] += rng.normal(0, sigma, (len(gt), 2))
    ids = np.arange(len(gt))
    r = metrics.ate(ids, est, ids, gt, align=False)
    # |e| with e ~ N(0, sigma^2 I_2): rms = sqrt(2) sigma, mean = sigma sqrt(pi/2)
    assert r["rmse_m"] == pytest.approx(np.sqrt(2) * sigma, rel=NOISY_RTOL)
    assert r["mean_m"] == pytest.approx(sigma * np.sqrt(np.pi / 2), rel=NOISY_RTOL)
    assert metrics.ate(ids, est, ids, gt)["rmse_m"] <= r["rmse_m"] + EXACT_TOL_M


def test_ate_matches_by_id():
    rng = np.random.default_rng(4)
    gt = _traj(rng, 50)
    ids = np.arange(50) * 2 + 10
    order = rng.permutation(50)[:30]
    est = gt[order].copy()
    est[:, 0] += 1.0
    r = metrics.ate(ids[order], est, ids, gt, align=False)
    assert r["n"] == 30 and r["rmse_m"] == pytest.approx(1.0, abs=EXACT_TOL_M)
    with pytest.raises(GraphSlamError):
        metrics.ate(np.array([10]), gt[:1], ids, gt)
    with pytest.raises(GraphSlamError):
        metrics.ate(np.array([11, 13]), gt[:2], ids, gt)


def test_rpe_sanity():
    rng = np.random.default_rng(5)
    gt = _traj(rng)
    ids = np.arange(len(gt))
    moved = _transform(gt, _rot(-1.1), np.array([3.0, 4.0]))
    r = metrics.rpe(ids, moved, ids, gt)
    assert r["trans_rmse_m"] < EXACT_TOL_M and r["rot_rmse_rad"] < 1e-12 and r["n"] == len(gt) - 1
    # a constant heading bias on every step shows as that rotation error
    est = gt.copy()
    bias = 0.01
    for k in range(1, len(gt)):
        rel = between(gt[k - 1:k], gt[k:k + 1])[0]
        rel[2] += bias
        c, s = np.cos(est[k - 1, 2]), np.sin(est[k - 1, 2])
        est[k] = [est[k - 1, 0] + c * rel[0] - s * rel[1], est[k - 1, 1] + s * rel[0] + c * rel[1],
                  metrics.wrap_angle(est[k - 1, 2] + rel[2])]
    r = metrics.rpe(ids, est, ids, gt, delta=1)
    assert r["rot_rmse_rad"] == pytest.approx(bias, abs=1e-12)
    assert r["trans_rmse_m"] < 1e-9
    assert metrics.rpe(ids, est, ids, gt, delta=5)["rot_rmse_rad"] == pytest.approx(5 * bias, abs=1e-12)
    with pytest.raises(GraphSlamError):
        metrics.rpe(ids, est, ids, gt, delta=0)


def test_pose_errors_wrap():
    est = np.array([[1.0, 2.0, np.pi - 0.1]])
    gt = np.array([[0.5, 2.5, -np.pi + 0.1]])
    e = metrics.pose_errors(est, gt)
    assert np.allclose(e, [[0.5, -0.5, -0.2]])


def test_nees_hand_computed():
    err = np.array([[1.0, 2.0], [0.5, -1.0]])
    cov = np.array([[[4.0, 0.0], [0.0, 1.0]], [[2.0, 1.0], [1.0, 2.0]]])
    # first: diagonal, 1/4 + 4; second: inv = [[2, -1], [-1, 2]] / 3
    e2 = np.array([0.5, -1.0])
    inv2 = np.array([[2.0, -1.0], [-1.0, 2.0]]) / 3.0
    expected = [1.0 / 4.0 + 4.0, e2 @ inv2 @ e2]
    assert np.allclose(metrics.nees(err, cov), expected, rtol=1e-12)
    assert expected[1] == pytest.approx((0.5 + 1.0 + 2.0) / 3.0)


def test_nees_is_chi2_for_consistent_errors():
    rng = np.random.default_rng(6)
    n, d = 20000, 3
    A = rng.normal(size=(n, d, d))
    cov = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(d)
    err = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, d)))
    assert metrics.nees(err, cov).mean() == pytest.approx(d, rel=0.03)


def test_chi2_bounds():
    lo, hi = metrics.chi2_bounds(3, 1, 0.95)
    assert lo == pytest.approx(0.2158, abs=1e-3) and hi == pytest.approx(9.348, abs=1e-3)
    lo50, hi50 = metrics.chi2_bounds(3, 50, 0.95)
    assert lo < lo50 < 3 < hi50 < hi
    with pytest.raises(GraphSlamError):
        metrics.chi2_bounds(0, 1)


def test_nees_of_a_singular_covariance_is_nan_not_a_crash():
    """Tenth hostile pass: FastSLAM with every robot started at its truth (a collapsed
    cloud: zero covariance) ended ``run --nees`` in LinAlgError, nothing written, and
    ``compare`` dropped the back end. The NEES of such a pose is undefined: NaN; the others
    are the same numbers as before."""
    rng = np.random.default_rng(0)
    err = rng.normal(size=(4, 3))
    A = rng.normal(size=(4, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    full = metrics.nees(err, P)
    P[1] = 0.0  # a cloud of one pose
    P[2] = np.diag([1.0, 1.0, 0.0])  # singular in heading only
    got = metrics.nees(err, P)
    assert np.isnan(got[1]) and np.isnan(got[2])
    assert got[0] == full[0] and got[3] == full[3]
    expected = err[0] @ np.linalg.solve(P[0], err[0])
    assert got[0] == pytest.approx(expected, rel=1e-12)


def test_a_run_whose_gate_rejects_most_sightings_says_so():
    """Tenth hostile pass: ``[ekf] known_gate_chi2_prob = 0.5`` gated out 623 of 866
    sightings (ATE that of dead reckoning) and the run said nothing; so did Victoria Park's
    EKF at its defaults (62 %). The default gate rejects none of the synthetic world's."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline

    ds = registry.load_dataset("synthetic")
    said = {}
    for prob in (0.5, 0.9999):
        be = registry.make_backend("ekf", overrides={"known_gate_chi2_prob": prob})
        result = pipeline.run(ds, be)
        assert result.observations == sum(len(f.observations) for f in ds.frames)
        assert result.observations_rejected == be.rejected_count
        m = pipeline.compute_metrics(result, with_graph_error=False)
        said[prob] = [w for w in m.warnings or [] if "rejected by the back end's gate" in w]
    assert len(said[0.5]) == 1 and said[0.9999] == []
    assert metrics.rejected_warning(10, 5) == [] and len(metrics.rejected_warning(10, 6)) == 1


def test_map_errors_count_the_true_landmarks_copies_share():
    """83 estimated landmarks matched on MRCLAM robot 3 were 15 true ones; the summary
    said "83 landmarks" (twelfth hostile pass)."""
    import numpy as np

    from graphslam.evaluation.planar import map_errors
    from slamcore.planar.records import Estimate

    ids = np.arange(3)
    wTb = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    est = Estimate(ids, wTb, np.array([10, 11, 12]), np.array([[0.0, 1.0], [0.1, 1.0], [5.0, 1.0]]))
    pairs = [(1, 10), (1, 11), (2, 12)]  # 10 and 11 are both true landmark 1
    out = map_errors(est, (ids, wTb), {1: (0.0, 1.0), 2: (5.0, 1.0)}, pairs)
    assert (out["landmarks_matched"], out["landmarks_matched_true"]) == (3, 2)


def test_a_landmark_is_recovered_only_by_an_estimate_of_its_own():
    """MRCLAM's landmarks lie 0.18-0.26 m apart: a landmark never seen was counted as
    recovered by its neighbour's estimate, 0.27 m away (fifteenth hostile pass)."""
    import numpy as np

    from graphslam.evaluation.planar import MAP_RECOVERY_RADIUS_M, map_errors
    from slamcore.planar.records import Estimate

    ids = np.arange(3)
    wTb = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    apart_m = 0.8 * MAP_RECOVERY_RADIUS_M  # closer than the radius, as MRCLAM's pairs are
    truth = {1: (0.0, 1.0), 2: (apart_m, 1.0), 3: (5.0, 1.0)}
    est = Estimate(ids, wTb, np.array([10, 12]), np.array([[0.0, 1.0], [5.0, 1.0]]))  # 2 never seen
    out = map_errors(est, (ids, wTb), truth, [(1, 10), (3, 12)])
    assert out["landmarks_recovered"] == 2
    # without labels (no association pairs): one estimate recovers one landmark at most
    assert map_errors(est, (ids, wTb), truth, [])["landmarks_recovered"] == 2
    # estimates whose sightings were of other landmarks recover none of them
    assert map_errors(est, (ids, wTb), truth, [(3, 10), (1, 12)])["landmarks_recovered"] == 0
