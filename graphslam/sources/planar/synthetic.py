"""A seeded synthetic 2-D landmark world driven around a closed route.

The robot drives a rounded rectangle ``laps`` times at constant speed (so the
start is revisited), measuring range and bearing to the point landmarks in
its field of view. Everything random comes from one
``np.random.default_rng(seed)``: the same config gives the same dataset to the
bit.

Noise model (course demo values are the defaults):

- motion: each step the commanded ``v`` (m/s) and ``w`` (rad/s) are corrupted by
  ``N(0, sigma_v^2)`` and ``N(0, sigma_w^2)``, held over the step and integrated
  exactly (unicycle arc) into the odometry ``[dx, dy, dtheta]``; its covariance
  is the first-order propagation ``J diag(sigma_v^2, sigma_w^2) J^T``;
- measurement: ``[range, bearing] + N(0, diag(sigma_r^2, sigma_phi^2))``.

Why ``dt_s = 1 s`` and ``speed_mps = 1 m/s`` by default: the course sigmas are
rates, and the noise per step scales with ``dt``. The heading random walk after
``N`` steps has std ``sigma_w dt sqrt(N)``; over a fixed route length ``L`` at
speed ``v`` that is ``sigma_w sqrt(L dt / v)``, so a high rate (small ``dt``)
makes odometry *more* accurate. Measured on the default ~770 m, 768-step
route (seeds 0-4), odometry-only ATE (aligned RMSE) is 1.1-2.7 m at
``dt = 1 s`` (2.27 m for seed 0, up to ~4-6 m worst pose) but only 0.3-0.7 m
at ``dt = 0.1 s``, too little for a landmark smoother to show much. At
``dt = 1 s`` the iSAM2 back end reaches 0.16-0.33 m (seeds 0-4), 5-11x
better, with the course noise values unchanged.

Why ``sensor_range_m = 8`` and ``world_margin_m = 8``: with the course's 10 deg
bearing noise a landmark at range r is known laterally to only ``0.17 r``; at
20 m the range-bearing model is so non-linear over that spread that EKF-SLAM
grows overconfident whatever its Jacobians (20 Monte Carlo runs: average pose
NEES inside its 95 % bounds on 54 % of the steps at 6 m with plain Jacobians,
under 1 % at 20 m with plain or observability-constrained Jacobians; 96 % at
8 m with the observability-constrained EKF of
``filters/ekf_slam.py``). Landmarks farther than the range from the route are
never seen, hence the margin. Defaults see ~1.1 landmarks per pose; 77 of the
200 are ever seen (seed 0).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from slamcore.config import Validated, bounded
from slamcore.errors import ConfigError
from slamcore.planar.geometry import compose, observe, wrap_angle
from slamcore.planar.records import Dataset, Frame, Observation, ObservationKind, Odometry, SensorField

#: Added to the odometry covariance diagonal: two velocity noises drive three
#: outputs, so ``J Q J^T`` is rank 2 (singular; on straights ``dy`` and
#: ``dtheta`` are fully correlated) and would be refused as not positive
#: definite. The floor makes it PD: variance 1e-6 on x, y (1 mm per step, think
#: of wheel slip) and 1e-7 on heading (0.3 mrad, against ~3e-6 rad^2 of real
#: per-step heading variance at the defaults). With 1e-7 on x, y too, runs
#: whose landmarks are out of sight for a while gave iSAM2 an indeterminate
#: system (information 1e7 along the singular direction).
ODOMETRY_COVARIANCE_FLOOR = np.diag([1e-6, 1e-6, 1e-7])

#: Prior on the first pose: variance 1e-6 (1 mm, 1 mrad std), i.e. the first
#: pose is known; it anchors the gauge of the graph.
PRIOR_VARIANCE = 1e-6

#: Longest run the world may generate: each step holds a frame with its
#: observations (about 1 kB), so 1e6 steps is already a few GB of frames.
MAX_STEPS = 1_000_000
#: More landmarks than this are not a 2-D SLAM benchmark but a memory test.
MAX_LANDMARKS = 1_000_000

#: Largest length of the world's geometry (route, margins, sensor range), m:
#: 1000 km is beyond any driven benchmark route and keeps every position far
#: inside the 1e9 m the pose-graph readers accept.
MAX_WORLD_M = 1e6
#: Largest speed, m/s (and speed noise): faster than sound; no ground robot.
MAX_SPEED_MPS = 1e3
#: Largest range noise std, m: 10 km is worse than any range sensor (lidar is
#: cm, radar m); near 1e154 its square (the covariance) overflows.
MAX_SIGMA_RANGE_M = 1e4
#: Smallest noise std of every measurement (range m, bearing deg, speed m/s, yaw
#: rate deg/s): a nano-unit is finer than any robot sensor (lidar ranges are mm,
#: a navigation-grade gyro drifts 0.01 deg/h), and it is the smallest noise the
#: filters' float64 safeguards are tested at (tests/filters/test_filter_robustness.py;
#: iSAM2 there falls back to QR). At 1e-30 m iSAM2's system was indeterminate where
#: it reads its estimate, and at 1e-320 the covariance underflowed to zero.
MIN_SIGMA = 1e-9
#: Largest angular noise std, degrees (bearing per sighting, yaw rate per
#: second): a wrapped normal of std 180 degrees is already nearly uniform on
#: the circle, so a larger value carries no more meaning, only overflow.
MAX_SIGMA_ANGLE_DEG = 180.0

#: Below this |w dt| (rad) the unicycle integration uses Taylor series.
_SMALL_ANGLE = 1e-4


@dataclass(frozen=True)
class SyntheticConfig(Validated):
    """Parameters of the synthetic world (section ``[synthetic]``).

    Route: a rounded rectangle ``route_length_m`` x ``route_width_m`` with
    corners of radius ``corner_radius_m``, driven counter-clockwise ``laps``
    times from ``(0, 0)`` heading +x (the start of the bottom straight).
    Landmarks: ``n_landmarks`` points drawn uniformly in the route's bounding box
    grown by ``world_margin_m``, at least ``landmark_clearance_m`` from the
    route; each has a signature drawn from ``[0, signature_count)`` (collisions
    possible, like real appearance).

    Attributes:
        seed: seed of the one ``np.random.default_rng`` that draws, in this order,
            the landmark positions, their signatures, the odometry noise and the
            measurement noise; also stored as the dataset's ``seed``. ``--seed``
            overrides it.
        n_landmarks: number of point landmarks (ids ``0 .. n_landmarks - 1``).
        route_length_m: extent of the rounded-rectangle route along x (the
            bottom straight, driven first towards +x), m. Each straight is
            ``route_length_m - 2 corner_radius_m`` rounded to whole steps of
            ``speed_mps * dt_s``.
        route_width_m: extent of the route along y, m; its straights are rounded
            to whole steps likewise.
        corner_radius_m: radius of the route's four quarter-circle corners, m;
            must be under half of ``route_length_m`` and ``route_width_m``. Each
            corner is driven in ``round(0.5 pi corner_radius_m / (speed_mps dt_s))``
            steps (at least 1) whose yaw rates turn exactly pi/2.
        laps: how many times the route is driven; each lap ends where it
            started (up to the rounding of the straights to whole steps).
        world_margin_m: landmarks are drawn uniformly in the bounding box of the
            true route grown by this on every side, m.
        landmark_clearance_m: least distance from a landmark to the true route
            (its poses and the midpoints between consecutive poses), m; drawn
            points nearer than this are rejected.
        signature_count: each landmark's signature is a uniform integer in
            ``[0, signature_count)``, attached to every observation of it. The
            filters read a signature only when an observation has no
            ``landmark_id``, and every synthetic observation has one; iSAM2 does
            not read it.
        speed_mps: true forward speed, constant over the whole route, m/s.
        dt_s: time step, s: one frame (``stamp_s = k dt_s``) and one odometry
            step every ``dt_s``, over which the noisy velocities are held. The
            number of steps, ``laps`` x perimeter / (``speed_mps`` x ``dt_s``),
            must be at most 1e6.
        sensor_range_m: a landmark is observed when its true range is at most
            this, m (and it is inside ``fov_deg``); the test is on the true
            measurement, before noise.
        fov_deg: full field of view of the sensor, centred on the heading,
            degrees: a landmark is observed when its true bearing is within
            ``fov_deg / 2`` of the heading.
        sigma_v_mps: standard deviation of the zero-mean Gaussian noise added
            to the forward speed of each step, m/s; also enters the odometry
            covariance.
        sigma_w_degps: standard deviation of the noise added to the yaw rate of
            each step, degrees/s (converted to rad/s); also enters the odometry
            covariance.
        sigma_r_m: standard deviation of the noise on each measured range, m;
            the observations' covariance is ``diag(sigma_r^2, sigma_phi^2)``.
            A noisy range <= 0 is dropped.
        sigma_phi_deg: standard deviation of the noise on each measured bearing,
            degrees (the covariance holds it in rad^2).
    """

    SECTION: ClassVar[str] = "synthetic"

    seed: int = bounded(0, min=0)
    n_landmarks: int = bounded(200, min=1, max=MAX_LANDMARKS)
    route_length_m: float = bounded(120.0, gt=0.0, max=MAX_WORLD_M)
    route_width_m: float = bounded(80.0, gt=0.0, max=MAX_WORLD_M)
    corner_radius_m: float = bounded(10.0, gt=0.0, max=MAX_WORLD_M)
    laps: int = bounded(2, min=1)
    world_margin_m: float = bounded(8.0, min=0.0, max=MAX_WORLD_M)
    landmark_clearance_m: float = bounded(2.0, min=0.0, max=MAX_WORLD_M)
    signature_count: int = bounded(1000, min=1)
    speed_mps: float = bounded(1.0, gt=0.0, max=MAX_SPEED_MPS)
    dt_s: float = bounded(1.0, gt=0.0)
    sensor_range_m: float = bounded(8.0, gt=0.0, max=MAX_WORLD_M)
    fov_deg: float = bounded(180.0, gt=0.0, max=360.0)
    sigma_v_mps: float = bounded(0.05, min=MIN_SIGMA, max=MAX_SPEED_MPS)
    sigma_w_degps: float = bounded(0.1, min=MIN_SIGMA, max=MAX_SIGMA_ANGLE_DEG)
    sigma_r_m: float = bounded(0.2, min=MIN_SIGMA, max=MAX_SIGMA_RANGE_M)
    sigma_phi_deg: float = bounded(10.0, min=MIN_SIGMA, max=MAX_SIGMA_ANGLE_DEG)

    def __post_init__(self):
        super().__post_init__()
        if 2.0 * self.corner_radius_m >= min(self.route_length_m, self.route_width_m):
            raise ConfigError(
                "synthetic.corner_radius_m must be less than half of route_length_m and route_width_m"
            )
        if (
            self.landmark_clearance_m
            >= self.world_margin_m + min(self.route_length_m, self.route_width_m) / 2
        ):
            raise ConfigError("synthetic.landmark_clearance_m leaves no room for landmarks")
        perimeter = 2 * (self.route_length_m + self.route_width_m) - (8 - 2 * np.pi) * self.corner_radius_m
        steps = self.laps * perimeter / (self.speed_mps * self.dt_s)
        if steps > MAX_STEPS:
            raise ConfigError(
                f"synthetic.dt_s: the route would take {steps:.3g} steps "
                f"(laps x perimeter / (speed_mps x dt_s)); at most {MAX_STEPS:.0e}"
            )

    def replace(self, **changes) -> SyntheticConfig:
        """A copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)


def route_controls(config: SyntheticConfig) -> np.ndarray:
    """(N, 2) true controls ``[v_mps, w_radps]`` of each step of the route.

    Straights are driven at ``w = 0``; each corner takes a whole number of steps
    whose yaw rates sum to exactly pi/2, so each lap turns by 2 pi and ends
    where it started (up to rounding of the straights to whole steps).
    """
    step_m = config.speed_mps * config.dt_s
    rc = config.corner_radius_m
    n_long = max(1, int(round((config.route_length_m - 2 * rc) / step_m)))
    n_wide = max(1, int(round((config.route_width_m - 2 * rc) / step_m)))
    n_corner = max(1, int(round(0.5 * np.pi * rc / step_m)))
    w_corner = 0.5 * np.pi / (n_corner * config.dt_s)
    lap = []
    for n_straight in (n_long, n_wide, n_long, n_wide):
        lap += [0.0] * n_straight + [w_corner] * n_corner
    w = np.tile(np.array(lap), config.laps)
    return np.stack([np.full_like(w, config.speed_mps), w], axis=-1)


def unicycle_delta(v: np.ndarray, w: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact body-frame motion of constant ``(v, w)`` over ``dt_s`` and its Jacobian.

    Args:
        v: (...) forward speed m/s; w: (...) yaw rate rad/s.

    Returns:
        delta: (..., 3) ``[dx_m, dy_m, dtheta_rad]``; J: (..., 3, 2) d delta / d(v, w).
    """
    v = np.asarray(v, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    a = w * dt_s
    small = np.abs(a) < _SMALL_ANGLE
    a_safe = np.where(small, 1.0, a)
    a2 = a * a
    # f = sin(a)/a, g = (1 - cos a)/a and their derivatives, series near 0.
    f = np.where(small, 1.0 - a2 / 6.0, np.sin(a_safe) / a_safe)
    g = np.where(small, a / 2.0 - a * a2 / 24.0, (1.0 - np.cos(a_safe)) / a_safe)
    df = np.where(small, -a / 3.0, (a_safe * np.cos(a_safe) - np.sin(a_safe)) / a_safe**2)
    dg = np.where(small, 0.5 - a2 / 8.0, (a_safe * np.sin(a_safe) - (1.0 - np.cos(a_safe))) / a_safe**2)
    s = v * dt_s
    delta = np.stack([s * f, s * g, a], axis=-1)
    J = np.zeros(np.shape(a) + (3, 2))
    J[..., 0, 0] = dt_s * f
    J[..., 1, 0] = dt_s * g
    J[..., 0, 1] = s * df * dt_s
    J[..., 1, 1] = s * dg * dt_s
    J[..., 2, 1] = dt_s
    return delta, J


def _place_landmarks(config: SyntheticConfig, route_xy: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n_landmarks, 2) landmark positions by seeded rejection sampling."""
    lo = route_xy.min(axis=0) - config.world_margin_m
    hi = route_xy.max(axis=0) + config.world_margin_m
    out = np.zeros((0, 2))
    for _ in range(1000):
        cand = rng.uniform(lo, hi, size=(2 * config.n_landmarks, 2))
        d2 = ((cand[:, None, :] - route_xy[None, :, :]) ** 2).sum(-1).min(axis=1)
        out = np.concatenate([out, cand[d2 >= config.landmark_clearance_m**2]])
        if len(out) >= config.n_landmarks:
            return out[: config.n_landmarks]
    raise ConfigError("[synthetic] could not place landmarks: clearance too large")  # pragma: no cover


def make_synthetic(config: SyntheticConfig | None = None) -> Dataset:
    """Simulate the world of ``config``; return a :class:`Dataset` named "synthetic".

    Frames: pose ids ``0..N`` (N = steps of the route), ``stamp_s = k dt_s``,
    ``wTb_true`` set; frame ``k >= 1`` has ``Odometry(k-1, k)``; every frame has
    the range-bearing observations of the landmarks within ``sensor_range_m``
    and ``fov_deg / 2`` of the heading (in landmark-id order), with known
    ``landmark_id`` and ``signature`` and ``true_landmark_ids``. A noisy range
    <= 0 (needs a 10-sigma draw with the default clearance) is dropped.
    """
    config = SyntheticConfig() if config is None else config
    rng = np.random.default_rng(config.seed)
    controls = route_controls(config)
    n_steps = controls.shape[0]
    dt = config.dt_s

    # True trajectory.
    true_delta, _ = unicycle_delta(controls[:, 0], controls[:, 1], dt)
    wTb = np.zeros((n_steps + 1, 3))
    for k in range(n_steps):
        wTb[k + 1] = compose(wTb[k], true_delta[k])

    # Landmarks, signatures (draw order fixed: landmarks, signatures, odometry, measurements).
    dense = np.concatenate([wTb[:, :2], 0.5 * (wTb[:-1, :2] + wTb[1:, :2])])
    landmarks = _place_landmarks(config, dense, rng)
    signatures = rng.integers(0, config.signature_count, size=config.n_landmarks)

    # Odometry: noisy velocities integrated over dt.
    sigma_w = np.deg2rad(config.sigma_w_degps)
    noise = rng.standard_normal((n_steps, 2)) * np.array([config.sigma_v_mps, sigma_w])
    noisy = controls + noise
    odo_delta, J = unicycle_delta(noisy[:, 0], noisy[:, 1], dt)
    Q = np.diag([config.sigma_v_mps**2, sigma_w**2])
    odo_cov = J @ Q @ np.swapaxes(J, -1, -2) + ODOMETRY_COVARIANCE_FLOOR

    # Observations.
    R = np.diag([config.sigma_r_m**2, np.deg2rad(config.sigma_phi_deg) ** 2])
    sig_z = np.array([config.sigma_r_m, np.deg2rad(config.sigma_phi_deg)])
    half_fov = 0.5 * np.deg2rad(config.fov_deg)
    frames = []
    for k in range(n_steps + 1):
        z_true = observe(wTb[k][None, :], landmarks)
        visible = np.flatnonzero((z_true[:, 0] <= config.sensor_range_m) & (np.abs(z_true[:, 1]) <= half_fov))
        z = z_true[visible] + rng.standard_normal((visible.size, 2)) * sig_z
        z[:, 1] = wrap_angle(z[:, 1])
        keep = z[:, 0] > 0.0
        obs = tuple(
            Observation(k, int(j), zj, R, ObservationKind.RANGE_BEARING, int(signatures[j]))
            for j, zj in zip(visible[keep], z[keep], strict=True)
        )
        odometry = None if k == 0 else Odometry(k - 1, k, odo_delta[k - 1], odo_cov[k - 1])
        truth = wTb[k].copy()
        truth.setflags(write=False)
        frames.append(
            Frame(
                pose_id=k,
                stamp_s=k * dt,
                odometry=odometry,
                observations=obs,
                wTb_true=truth,
                true_landmark_ids=tuple(int(j) for j in visible[keep]),
            )
        )
    return Dataset(
        name="synthetic",
        frames=frames,
        prior_wTb=wTb[0].copy(),
        prior_covariance=PRIOR_VARIANCE * np.eye(3),
        landmarks_true={i: landmarks[i].copy() for i in range(config.n_landmarks)},
        has_timestamps=True,
        seed=config.seed,
        # the simulated sensor reports every landmark of its field (before the noise)
        sensor_field=SensorField(config.sensor_range_m, min(half_fov, np.pi), 1.0),
    )
