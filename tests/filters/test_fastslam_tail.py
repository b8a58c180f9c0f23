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
    fixed = FastSlamConfig(
        version=version, association="unknown", n_particles=20, new_landmark_mahalanobis_sq=13.8155
    )
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


# --- sightings correlated in time: the weights take the new information only -----------


def _timed(z, stamp, model, pose_id=1):
    from slamcore.planar.records import Observation

    return Observation(
        pose_id=pose_id,
        landmark_id=0,
        z=np.array(z),
        covariance=np.diag([0.05**2, 0.01**2]),
        stamp_s=stamp,
        correlation=model,
    )


def test_weight_shares_read_each_records_last_sighting_by_the_same_sensor():
    from filters.fastslam_map import ParticleMaps
    from filters.fastslam_update import weight_shares
    from slamcore.planar.sighting_correlation import SightingCorrelation

    model = SightingCorrelation(time_constant_s=5.0, range_share=0.9, bearing_share=0.5, sensor=1)
    other = SightingCorrelation(time_constant_s=5.0, range_share=0.9, bearing_share=0.5, sensor=2)
    maps = ParticleMaps(3)
    c = maps.add_column(0)
    sl = maps.allocate(np.arange(3), c)
    maps.pool_seen[sl] = [10.0, 9.0, -np.inf]  # the third: never seen with a time
    maps.pool_sensor[sl] = 1
    p = maps.table[:, c]
    got = weight_shares(maps, p, [_timed([2.0, 0.1], 10.5, model)], 0)
    np.testing.assert_allclose(got, [model.weight_share(0.5), model.weight_share(1.5), 1.0])
    assert np.all(weight_shares(maps, p, [_timed([2.0, 0.1], 10.5, other)], 0) == 1.0)  # another camera
    assert weight_shares(maps, p, [_timed([2.0, 0.1], None, model)], 0) is None  # no time: independent


@pytest.mark.parametrize("version", [1, 2])
def test_a_burst_of_correlated_sightings_weighs_as_little_as_it_tells(version):
    """Two particles a little apart see one landmark ten times within a second: taken as
    independent, the burst's likelihood ratio compounds ten times; tempered, the nine
    repeats add their weight shares (about 0.05 each at 0.1 s apart with tau 7 s)."""
    from filters.fastslam import FastSlam
    from filters.fastslam_config import FastSlamConfig
    from slamcore.planar.records import Odometry
    from slamcore.planar.sighting_correlation import SightingCorrelation

    model = SightingCorrelation(time_constant_s=7.0, range_share=0.9, bearing_share=0.5)

    def spread(temper: bool) -> float:
        fs = FastSlam(
            FastSlamConfig(
                version=version, n_particles=2, resample_ess_fraction=0.0, temper_correlated=temper
            )
        )
        fs.initialize(0, np.zeros(3), np.eye(3) * 1e-12)
        fs.particles.poses[:] = [[0.0, 0.0, 0.0], [0.0, 0.05, 0.0]]
        for k in range(10):
            fs.predict(Odometry(k, k + 1, np.zeros(3), np.eye(3) * 1e-12), k + 1)
            fs.update([_timed([2.0, 0.02], 0.1 * k, model, pose_id=k + 1)])
        lw = fs.particles.logw
        return float(abs(lw[0] - lw[1]))

    full, tempered = spread(False), spread(True)
    assert tempered < 0.5 * full, (tempered, full)


def test_temper_correlated_on_data_without_a_correlation_is_said_to_do_nothing(tmp_path, capsys):
    from graphslam.cli.main import main

    cfg = tmp_path / "c.toml"
    cfg.write_text("[fastslam]\ntemper_correlated = false\n")
    assert (
        main(["run", *"--backend fastslam2 --max-steps 20 --rerun off --quiet".split(),
              "--config", str(cfg), "--out", str(tmp_path / "o")])
        == 0
    )
    err = capsys.readouterr().err
    assert "temper_correlated did nothing" in err and "correlate in time" in err, err


# -- the particles weighed by the sensor's error law ----------------------------------

#: Agreement of two evaluations of one log density, nats.
LOG_DENSITY_TOL = 1e-10
#: Agreement of a weight ratio with the law's, nats: the start cloud's 1e-6 m spread
#: (covariance 1e-12) moves each particle's landmark by as much.
LOG_GAP_TOL = 1e-4


@pytest.mark.parametrize("dof", [1.5, 5.1, 30.0, math.inf])
def test_log_likelihood_is_scipys_bivariate_density(dof):
    from scipy.stats import multivariate_normal, multivariate_t

    from filters.fastslam_math import inverse_sym2, log_likelihood

    rng = np.random.default_rng(7)
    for _ in range(20):
        A = rng.normal(size=(2, 2))
        S = A @ A.T + 0.1 * np.eye(2)
        nu = rng.normal(size=2) * 3.0
        inv, det = inverse_sym2(S[0, 0], S[0, 1], S[1, 1])
        got = log_likelihood(np.array([nu[0]]), np.array([nu[1]]), inv, det, dof)[0]
        law = (
            multivariate_normal(np.zeros(2), S) if math.isinf(dof) else multivariate_t(np.zeros(2), S, df=dof)
        )
        assert got == pytest.approx(law.logpdf(nu), abs=LOG_DENSITY_TOL)


def test_an_outlier_costs_a_heavy_tailed_sensor_a_logarithm_not_its_square():
    """FastSLAM 1.0, two particles, one of them 0.6 m further from the landmark than
    the sighting says (about 4 sigmas of its innovation): its weight against the other's
    is the law's density ratio, scipy's t(5.1) under the camera's law (e^-5.3), the
    Gaussian's without one (e^-8.9)."""
    from scipy.stats import multivariate_normal, multivariate_t

    shift_m = 0.6

    def log_gap(field: SensorField | None):
        slam = FastSlam(FastSlamConfig(version=1, n_particles=2, resample_ess_fraction=0.0))
        slam.initialize(0, np.zeros(3), np.eye(3) * 1e-12)
        slam.set_sensor_field(field)
        z = models.observe(np.zeros(3), LANDMARK)
        slam.update([Observation(0, 7, z, R)])
        slam.predict(Odometry(0, 1, np.zeros(3), np.eye(3) * 1e-12), 1)
        slam.particles.poses[:] = [[0.0, 0.0, 0.0], [-shift_m, 0.0, 0.0]]
        P = slam.maps.pool_cov[slam.maps.table[0, 0]]  # one record, shared before the update
        slam.update([Observation(1, 7, z, R)])
        w = slam.weights
        return math.log(w[1] / w[0]), P

    gap, P = log_gap(SensorField(10.0, math.pi / 2, 1.0, 5.1))
    # H_m for a landmark straight ahead at range r: d range / dx = 1, d bearing / dy = 1/r
    S_on, S_far = (np.diag([1.0, 1.0 / r]) @ P @ np.diag([1.0, 1.0 / r]) + R for r in (4.0, 4.0 + shift_m))
    t_on, t_far = (multivariate_t(np.zeros(2), S, df=5.1) for S in (S_on, S_far))
    assert gap == pytest.approx(t_far.logpdf([-shift_m, 0.0]) - t_on.logpdf([0.0, 0.0]), abs=LOG_GAP_TOL)
    gaussian, _ = log_gap(None)
    g_on, g_far = (multivariate_normal(np.zeros(2), S) for S in (S_on, S_far))
    assert gaussian == pytest.approx(g_far.logpdf([-shift_m, 0.0]) - g_on.logpdf([0.0, 0.0]), abs=LOG_GAP_TOL)
    assert gaussian < gap - 3.0  # the tail forgives the outlier e^3.6 of the Gaussian's cost


@pytest.mark.parametrize("dof", [5.1, math.inf])
def test_a_robot_sighting_weighs_the_particles_by_the_cameras_law(dof):
    """One camera sees landmarks and robots: a sighting of one robot by another weighs
    the particles by the law the landmarks' sightings use (the Gaussian it used alone
    made the robot sightings the only ones an outlier costs its square)."""
    from scipy.stats import multivariate_normal, multivariate_t

    from filters.fastslam_particles import ParticleSet

    particles = ParticleSet(FastSlamConfig(version=1, n_particles=2))
    particles.set_error_dof(dof)
    seen = np.array([[4.0, 0.0, 0.0], [4.6, 0.0, 0.0]])  # the second 0.6 m beyond the sighting
    before = particles.logw.copy()
    particles.weigh_sighting(np.zeros((2, 3)), seen, np.array([4.0, 0.0]), R)
    law = multivariate_normal(np.zeros(2), R) if math.isinf(dof) else multivariate_t(np.zeros(2), R, df=dof)
    gap = (particles.logw[1] - before[1]) - (particles.logw[0] - before[0])
    assert gap == pytest.approx(law.logpdf([-0.6, 0.0]) - law.logpdf([0.0, 0.0]), abs=LOG_DENSITY_TOL)


#: Agreement of the elementwise landmark update with a dense EKF step, metres / m^2.
EKF_STEP_TOL = 1e-12


@pytest.mark.parametrize("dof", [5.1, math.inf])
def test_a_landmark_takes_an_outlier_by_the_laws_weight(dof):
    """The landmark EKF step under the sensor's law is a dense EKF step with R times
    ``max(1, (v + d^2) / (v + 2))`` (d^2 the innovation's under S), its log density the
    law's under the unscaled S: before, an outlier moved the landmark as far as an inlier
    (MRCLAM landmark 20 of robots 3 and 5 ended 0.39 m off with the barcodes given)."""
    from scipy.stats import multivariate_normal, multivariate_t

    from filters.fastslam_math import landmark_update, range_bearing, t_noise_factor

    pose = np.array([0.2, -0.1, 0.3])
    m = np.array([3.0, 1.5])
    P = np.array([[0.04, 0.01], [0.01, 0.03]])
    z0 = models.observe(pose, m)
    a, b, c, d, _, _ = range_bearing(pose[0], pose[1], pose[2], m[0], m[1], z0[0], z0[1])
    H = np.array([[a, b], [c, d]])
    S = H @ P @ H.T + R
    for sigmas in (0.0, 1.0, 6.0):  # the range innovation in sigmas of S: inlier to outlier
        z = z0 + np.array([sigmas * math.sqrt(S[0, 0]), 0.0])
        *_, nu_r, nu_b = (np.atleast_1d(v) for v in range_bearing(pose[0], pose[1], pose[2], m[0], m[1], *z))
        step = (*(np.atleast_1d(v) for v in (a, b, c, d)), nu_r, nu_b, P[0, 0], P[0, 1], P[1, 1])
        step = (*step, R[0, 0], R[0, 1], R[1, 1], dof)
        dmx, dmy, Pn, logl, f = landmark_update(*step, robust=True)
        nu = np.array([nu_r[0], nu_b[0]])
        d2 = nu @ np.linalg.solve(S, nu)
        want_f = 1.0 if math.isinf(dof) else max(1.0, (dof + d2) / (dof + 2.0))
        assert np.all(f == pytest.approx(want_f, rel=1e-12))
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + want_f * R)
        assert np.array([dmx[0], dmy[0]]) == pytest.approx(K @ nu, abs=EKF_STEP_TOL)
        P_want = P - K @ H @ P
        assert np.array([Pn[0][0], Pn[1][0], Pn[2][0]]) == pytest.approx(
            [P_want[0, 0], P_want[0, 1], P_want[1, 1]], abs=EKF_STEP_TOL
        )
        law = (
            multivariate_normal(np.zeros(2), S) if math.isinf(dof) else multivariate_t(np.zeros(2), S, df=dof)
        )
        assert logl[0] == pytest.approx(law.logpdf(nu), abs=LOG_DENSITY_TOL)
        # FastSLAM 1.0's step (robust False) is the Gaussian one whatever the law
        *_, f_plain = landmark_update(*step)
        assert f_plain == 1.0
    if not math.isinf(dof):  # 6 sigmas in range: d^2 >= 36, R taken at least 5.8 times
        assert f[0] >= (dof + 36.0) / (dof + 2.0)
    assert t_noise_factor(np.zeros(1), np.zeros(1), (1.0, 0.0, 1.0), dof) == pytest.approx(1.0)


@pytest.mark.parametrize("version", [1, 2])
def test_after_2_0s_draw_a_landmark_takes_an_outlier_by_the_laws_weight(version):
    """One particle, a landmark seen once, then a sighting 1 m long in range: under the
    camera's t(5.1) law FastSLAM 2.0's landmark moves less than under a Gaussian (the
    EKF step after the draw takes R times the law's factor); 1.0's moves as far (its
    innovations are mostly its pose sample's error, filters/fastslam_math.py)."""

    def landmark_after_outlier(field: SensorField | None) -> np.ndarray:
        slam = FastSlam(FastSlamConfig(version=version, n_particles=1, seed=0))
        slam.initialize(0, np.zeros(3), np.eye(3) * 1e-12)
        slam.set_sensor_field(field)
        # the 1 m outlier (d2 50) lies beyond a Gaussian's misread gate (13.8), which
        # would keep it from the landmark altogether: opened, to compare the steps
        slam._particles.misread_gate_d2 = math.inf
        z = models.observe(np.zeros(3), LANDMARK)
        slam.update([Observation(0, 7, z, R)])
        slam.predict(Odometry(0, 1, np.zeros(3), np.eye(3) * 1e-12), 1)
        slam.update([Observation(1, 7, z + np.array([1.0, 0.0]), R)])
        return np.asarray(slam.estimate().landmarks_w)[0]

    heavy = landmark_after_outlier(SensorField(10.0, math.pi / 2, 1.0, 5.1))
    gaussian = landmark_after_outlier(None)
    moved_heavy, moved_gaussian = (float(np.linalg.norm(m - LANDMARK)) for m in (heavy, gaussian))
    assert moved_gaussian > 0.3  # two sightings of equal noise: about half of the 1 m
    if version == 2:
        assert moved_heavy < 0.5 * moved_gaussian
    else:
        assert moved_heavy == pytest.approx(moved_gaussian, abs=1e-9)


#: A misread barcode: landmark 7 is reported where another landmark lies, 3 m off to
#: the left (MRCLAM robot 5 read landmark 8 as 18 four frames running).
MISREAD_Z = np.array([3.0, math.pi / 2])
#: One motion step's noise: 2 cm and 0.01 rad.
STEP_COV = np.diag([0.02**2, 0.02**2, 0.01**2])


def _known_id_slam(n_particles: int, cloud_cov: np.ndarray) -> FastSlam:
    """FastSLAM 2.0, known ids, the camera's t(5.1) law; landmark 7 mapped from pose 0."""
    slam = FastSlam(FastSlamConfig(version=2, n_particles=n_particles, seed=0))
    slam.initialize(0, np.zeros(3), cloud_cov)
    slam.set_sensor_field(SensorField(10.0, math.pi, 1.0, 5.1))
    for _ in range(3):
        slam.update([Observation(0, 7, models.observe(np.zeros(3), LANDMARK), R)])
    return slam


def test_a_misread_id_leaves_2_0s_proposal_to_the_motion():
    """Every particle sees the misread far outside the gate: its pose is the motion draw
    (within 5 sigma of one step's noise), and the count says so; with the gate opened
    the same sighting turns the particles by more than 20 sigma."""

    def poses_after_misread(gate_d2: float | None) -> tuple[np.ndarray, int]:
        slam = _known_id_slam(50, np.eye(3) * 1e-10)
        if gate_d2 is not None:
            slam._particles.misread_gate_d2 = gate_d2
        slam.predict(Odometry(0, 1, np.zeros(3), STEP_COV), 1)
        slam.update([Observation(1, 7, MISREAD_Z, R)])
        counts = (slam._particles.misreads, slam.rejected_observations(), slam.associations())
        return slam._particles.poses.copy(), counts

    poses, counts = poses_after_misread(None)
    assert counts == (50, 1, [None])  # unused in the estimate, as the EKF's gated ones
    assert np.all(np.abs(poses) <= 5.0 * np.sqrt(np.diag(STEP_COV)))
    pulled, _ = poses_after_misread(math.inf)
    assert np.median(np.abs(pulled[:, 2])) > 20.0 * math.sqrt(STEP_COV[2, 2])


#: A motion step in the dark: 5 cm and 0.05 rad (forty of them spread the cloud's
#: headings to about 0.32 rad; the bearing's gate under one step's noise is 0.44 rad).
DARK_STEP_COV = np.diag([0.05**2, 0.05**2, 0.05**2])
DARK_STEPS = 40


def test_a_sighting_that_closes_a_drift_still_refines_every_proposal():
    """After forty motion steps without a sighting the cloud has spread; a true sighting
    of landmark 7 then lies beyond the gate under one step's noise for many particles
    (counted here, so the case is real) but inside the gate widened by the cloud's
    spread: no particle takes it as a misread, and the proposal pulls each particle's
    bearing to the landmark onto the sighting."""
    slam = _known_id_slam(200, np.eye(3) * 1e-10)
    for k in range(DARK_STEPS):
        slam.predict(Odometry(k, k + 1, np.zeros(3), DARK_STEP_COV), k + 1)
    z = models.observe(np.zeros(3), LANDMARK)

    def bearing_errors(poses: np.ndarray) -> np.ndarray:
        return np.array([models.wrap_angle(models.observe(x, LANDMARK)[1] - z[1]) for x in poses])

    before = bearing_errors(slam._particles.poses)
    one_step_sd = math.sqrt(R[1, 1] + DARK_STEP_COV[2, 2] + R[1, 1])  # sighting, step, map
    assert np.sum(before**2 / one_step_sd**2 > t2_quantile(0.999, 5.1)) >= 10
    slam.predict(Odometry(DARK_STEPS, DARK_STEPS + 1, np.zeros(3), DARK_STEP_COV), DARK_STEPS + 1)
    slam.update([Observation(DARK_STEPS + 1, 7, z, R)])
    assert (slam._particles.misreads, slam.rejected_observations()) == (0, 0)
    after = bearing_errors(slam._particles.poses)
    assert np.max(np.abs(after)) < 0.25 * np.max(np.abs(before))


def test_the_misread_gates_widened_distance_is_the_full_matrix_product():
    """:func:`widened_d2` adds ``H_x C H_x^T`` to the proposal's ``L`` in scalars; against
    ``nu^T (H_x (S + C) H_x^T + n)^-1 nu`` written with matrices, seeded random poses."""
    from filters.fastslam_math import proposal_update, range_bearing, widened_d2

    rng = np.random.default_rng(7)
    n = 50
    x = rng.normal(0.0, 2.0, (n, 3))
    m = rng.normal(0.0, 5.0, (n, 2))
    A = rng.normal(0.0, 0.1, (n, 3, 3))
    S = A @ A.transpose(0, 2, 1) + 1e-4 * np.eye(3)
    B = rng.normal(0.0, 0.2, (3, 3))
    C = B @ B.T
    z = np.array([4.0, 0.3])
    a, b, c, d, nu_r, nu_b = range_bearing(x[:, 0], x[:, 1], x[:, 2], m[:, 0], m[:, 1], z[0], z[1])
    noise = (np.full(n, 0.02), np.full(n, 0.001), np.full(n, 0.003))
    L = proposal_update(S, a, b, c, d, nu_r, nu_b, *noise)[-1]
    H = np.zeros((n, 2, 3))
    H[:, 0, :2] = np.stack([-a, -b], -1)
    H[:, 1, :] = np.stack([-c, -d, -np.ones(n)], -1)
    N = np.stack([np.stack([noise[0], noise[1]], -1), np.stack([noise[1], noise[2]], -1)], -2)
    full = H @ (S + C) @ H.transpose(0, 2, 1) + N
    nu = np.stack([nu_r, nu_b], -1)
    expected = np.einsum("ni,ni->n", nu, np.linalg.solve(full, nu[..., None])[..., 0])
    np.testing.assert_allclose(widened_d2(L, C, a, b, c, d, nu_r, nu_b), expected, rtol=1e-10)


#: Seconds between sightings in the misread-run tests (MRCLAM's camera: about 0.2-0.4 s).
SIGHTING_DT_S = 0.5
#: A second landmark, mapped right, seen beside landmark 7 where a scan confirms the pose.
LANDMARK_8 = np.array([3.0, 2.0])


def _scans_of_7(z: np.ndarray, n: int, t0_s: float, first_pose: int, with_8: bool = True):
    """``n`` scans ``(pose id, time, odometry, observations)``, one per motion step,
    ``SIGHTING_DT_S`` apart: landmark 7 at ``z`` and, ``with_8``, landmark 8 where it is."""
    z8 = models.observe(np.zeros(3), LANDMARK_8)
    for j in range(n):
        k, t = first_pose + j, t0_s + j * SIGHTING_DT_S
        scan = [Observation(k, 7, z, R, stamp_s=t)]
        if with_8:
            scan.append(Observation(k, 8, z8, R, stamp_s=t))
        yield k, t, Odometry(k - 1, k, np.zeros(3), np.eye(3) * 1e-8), scan


def _sightings_of_7(slam: FastSlam, z: np.ndarray, n: int, t0_s: float, first_pose: int, with_8: bool = True) -> None:
    """:func:`_scans_of_7` fed to ``slam``."""
    for k, _, odometry, scan in _scans_of_7(z, n, t0_s, first_pose, with_8):
        slam.predict(odometry, k)
        slam.update(scan)


def _landmark_7(slam: FastSlam) -> np.ndarray:
    est = slam.estimate()
    return np.asarray(est.landmarks_w)[list(est.landmark_ids).index(7)]


def _slam_7_from_a_misread(restart_s: float, with_8: bool) -> FastSlam:
    """Landmark 7's record built from three misreads (3 m to the left), then 20 true
    sightings over 9.5 s, with landmark 8 in the same scans or alone."""
    slam = FastSlam(FastSlamConfig(version=2, n_particles=20, seed=0, misread_restart_s=restart_s))
    slam.initialize(0, np.zeros(3), np.eye(3) * 1e-10)
    slam.set_sensor_field(SensorField(10.0, math.pi, 1.0, 5.1))
    _sightings_of_7(slam, MISREAD_Z, 3, 0.0, 1)
    _sightings_of_7(slam, models.observe(np.zeros(3), LANDMARK), 20, 10.0, 4, with_8)
    return slam


def test_a_record_every_later_sighting_misreads_starts_again():
    """Every true sighting of landmark 7 after its misread record lies beyond the misread
    gate, while landmark 8 in the same scans is taken in (the pose holds). Once they have
    been held out for longer than ``misread_restart_s``, each particle's record starts
    again from the sighting and the later sightings refine it: the estimate ends on the
    landmark. Without the restart (a run that never ends) the record stays 3 m off."""
    slam = _slam_7_from_a_misread(5.0, with_8=True)
    assert np.linalg.norm(_landmark_7(slam) - LANDMARK) < 0.05
    assert slam._particles.misread_restarts == 20  # every particle, once
    assert slam.restarted_landmark_records() == 20
    stuck = _slam_7_from_a_misread(1e9, with_8=True)
    assert np.linalg.norm(_landmark_7(stuck) - LANDMARK) > 2.5 and stuck._particles.misread_restarts == 0


def test_restarted_records_reach_metrics_and_the_summary():
    """The same sightings as a dataset through the pipeline: the 20 restarts are in the
    run's metrics (``records_restarted``) and its summary, and a run without one leaves
    the field out."""
    from graphslam import registry
    from graphslam.cli.run.planar import format_summary
    from graphslam.pipelines import planar as pipeline
    from slamcore.planar.records import Dataset, Frame

    scans = [*_scans_of_7(MISREAD_Z, 3, 0.0, 1), *_scans_of_7(models.observe(np.zeros(3), LANDMARK), 20, 10.0, 4)]
    frames = [Frame(0, stamp_s=0.0)]
    frames += [Frame(k, stamp_s=t, odometry=odo, observations=scan) for k, t, odo, scan in scans]
    data = Dataset("misread", frames, prior_covariance=np.eye(3) * 1e-10, has_timestamps=True,
                   sensor_field=SensorField(10.0, math.pi, 1.0, 5.1))
    for restart_s, expected in ((5.0, 20), (1e9, None)):
        backend = registry.make_backend("fastslam2", overrides={"n_particles": 20, "misread_restart_s": restart_s})
        metrics = pipeline.compute_metrics(pipeline.run(data, backend), with_graph_error=False)
        assert metrics.records_restarted == expected
        assert ("records restarted" in format_summary(metrics)) == (expected is not None)


def test_a_record_is_kept_where_no_other_sighting_confirms_the_pose():
    """The same sightings of landmark 7 alone: nothing tells a wrong record from a wrong
    pose (MRCLAM's joint run: a robot off in every particle held out its sightings of
    landmarks the others had mapped), so no record starts again."""
    slam = _slam_7_from_a_misread(5.0, with_8=False)
    assert slam._particles.misread_restarts == 0
    assert np.linalg.norm(_landmark_7(slam) - MISREAD_Z[0] * np.array([0.0, 1.0])) < 0.05


def test_a_burst_of_misreads_as_long_as_the_cameras_leaves_the_record():
    """Robot 5 of MRCLAM Dataset 6 misread one barcode four frames running over 1.16 s, the
    longest run under its truth: a burst of four misreads 0.5 s apart (1.5 s), landmark 8
    taken in beside them, restarts nothing, and the record stays on the landmark."""
    slam = _known_id_slam(20, np.eye(3) * 1e-10)
    _sightings_of_7(slam, MISREAD_Z, 4, 0.0, 1)
    assert slam._particles.misreads == 80
    _sightings_of_7(slam, models.observe(np.zeros(3), LANDMARK), 3, 3.0, 5)
    assert slam._particles.misread_restarts == 0
    assert np.linalg.norm(_landmark_7(slam) - LANDMARK) < 0.05


@pytest.mark.parametrize(
    "extra, words",
    [("", "sightings with a time stamp"), ('association = "unknown"\n', 'association = "known" and version = 2')],
)
def test_misread_restart_where_it_cannot_act_is_said_to_do_nothing(tmp_path, capsys, extra, words):
    """The synthetic world's sightings have no stamps, and unknown ids have no misread gate."""
    from graphslam.cli.main import main

    cfg = tmp_path / "c.toml"
    cfg.write_text(f"[fastslam]\nmisread_restart_s = 2.0\n{extra}")
    argv = ["run", *"--backend fastslam2 --max-steps 20 --rerun off --quiet".split(), "--config", str(cfg)]
    assert main([*argv, "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "misread_restart_s did nothing" in err and words in err, err
