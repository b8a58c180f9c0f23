"""Tiny seeded 2-D worlds for contract tests (independent of the synthetic module)."""

from __future__ import annotations

import numpy as np

from slamcore.planar import geometry as models
from slamcore.planar.records import Dataset
from slamcore.planar.records import Frame, LoopClosure, Observation, Odometry


def square_world(seed: int = 0, noise: bool = True, steps_per_side: int = 10,
                 sigma_xy_m: float = 0.02, sigma_th_rad: float = 0.005,
                 sigma_r_m: float = 0.05, sigma_b_rad: float = 0.01,
                 sensor_range_m: float = 6.0, loop_closure: bool = True,
                 reverse_every: int = 0, known_ids: bool = True) -> Dataset:
    """A robot drives twice around a 10 m square past 12 landmarks.

    ``reverse_every``: store every n-th odometry edge new->old (as pose-graph files do).
    """
    rng = np.random.default_rng(seed)
    side = 10.0
    step = side / steps_per_side
    lms = {j: p for j, p in enumerate(rng.uniform([-3, -3], [13, 13], size=(12, 2)))}
    u_true = []
    for lap in range(2):
        for s in range(4):
            u_true += [np.array([step, 0.0, 0.0])] * (steps_per_side - 1)
            u_true.append(np.array([step, 0.0, np.pi / 2]))
    wTb = [np.zeros(3)]
    for u in u_true:
        wTb.append(models.compose(wTb[-1], u))
    odo_cov = np.diag([sigma_xy_m**2, sigma_xy_m**2, sigma_th_rad**2])
    z_cov = np.diag([sigma_r_m**2, sigma_b_rad**2])
    frames = []
    for k, pose in enumerate(wTb):
        odo = None
        if k > 0:
            u = u_true[k - 1].copy()
            if noise:
                u = u + rng.normal(0, [sigma_xy_m, sigma_xy_m, sigma_th_rad])
            if reverse_every and k % reverse_every == 0:
                c, s = np.cos(u[2]), np.sin(u[2])
                inv = np.array([-c * u[0] - s * u[1], s * u[0] - c * u[1], -u[2]])
                J = np.array([[-c, -s, s * u[0] - c * u[1]],
                              [s, -c, c * u[0] + s * u[1]],
                              [0, 0, -1.0]])
                odo = Odometry(k, k - 1, inv, J @ odo_cov @ J.T)
            else:
                odo = Odometry(k - 1, k, u, odo_cov)
        obs, truth = [], []
        for j, m in lms.items():
            z = models.observe(pose, m)
            if z[0] < sensor_range_m:
                if noise:
                    z = z + rng.normal(0, [sigma_r_m, sigma_b_rad])
                obs.append(Observation(k, j if known_ids else None, z, z_cov, signature=j))
                truth.append(j)
        lcs = ()
        if loop_closure and k == len(wTb) - 1:
            # the last pose revisits pose 0 (same place, same heading after two laps)
            lcs = (LoopClosure(0, k, np.zeros(3), odo_cov),)
        frames.append(Frame(k, float(k), odo, tuple(obs), lcs, pose, tuple(truth)))
    return Dataset("square", frames, prior_wTb=np.zeros(3), prior_covariance=np.eye(3) * 1e-6,
                   landmarks_true=lms, has_timestamps=True)


def assert_poses_close(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Compare (N, 3) poses with the heading difference wrapped (pi == -pi)."""
    from slamcore.planar.geometry import wrap_angle

    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d[..., 2] = wrap_angle(d[..., 2])
    np.testing.assert_allclose(d, 0.0, atol=atol)
