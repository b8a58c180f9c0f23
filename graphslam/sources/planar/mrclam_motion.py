"""Commanded-velocity odometry of the UTIAS MRCLAM robots, integrated between frames.

Pure functions (numpy and floats, no file I/O) so that the reader
(:mod:`graphslam.sources.planar.mrclam`) and the calibration
(``benchmarks/calibrate_mrclam.py``) integrate the same way.

The log holds *commanded* forward and angular velocities ``(t_i, v_i, w_i)`` at
60-100 Hz with uneven steps. Each command is held from ``t_i + lag`` until the next
command's time (zero-order hold: that is what the robot's controller did with it),
and the unicycle is integrated exactly over each held interval (a circular arc).
The robots turn commands into motion with a delay and drive slower than
commanded; both are sensor properties of these iRobot Create robots, calibrated
against the Vicon truth (:class:`MotionModel`).

Noise model (per held interval of ``dt`` seconds, ``ds = v dt`` metres,
``dtheta = w dt`` radians), expressed in the interval's mid-heading frame::

    var_along   = a_s |ds| + b_s dt
    var_lateral = a_y |ds|
    var_heading = a_theta |dtheta| + c_theta |ds| + b_theta dt

and propagated to first order along the integrated path: the covariance of the
relative pose between two frames is ``sum_k J_k Q_k J_k^T``. Variance
proportional to distance and to turned angle is the classic odometry model
(Thrun et al., *Probabilistic Robotics*, 5.4); the ``dt`` terms are the drift of
a robot told to stand still, which the truth shows (about 2-5 mm/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Added to every relative-pose covariance's diagonal (x, y m^2; heading rad^2):
#: two frames at the same instant have zero motion and would give a singular
#: covariance, which no solver can weigh. 1e-8 is 0.1 mm and 0.1 mrad of std,
#: far below the few millimetres a held interval of these logs adds.
COVARIANCE_FLOOR = np.diag([1e-8, 1e-8, 1e-8])


@dataclass(frozen=True)
class MotionModel:
    """How commanded velocities become motion, and how uncertain that is.

    Attributes:
        lag_s: a command takes effect this long after its time stamp.
        forward_scale, angular_scale: the robot drives ``scale * commanded``.
        a_s, b_s, a_y, a_theta, c_theta, b_theta: the noise model's coefficients
            (module docstring), in m, m^2/s, m, rad, rad^2/m, rad^2/s.
    """

    lag_s: float
    forward_scale: float
    angular_scale: float
    a_s: float
    b_s: float
    a_y: float
    a_theta: float
    c_theta: float
    b_theta: float

    def coefficients(self) -> tuple[float, ...]:
        return (self.a_s, self.b_s, self.a_y, self.a_theta, self.c_theta, self.b_theta)


def held_commands(
    times_s: np.ndarray, v_mps: np.ndarray, w_radps: np.ndarray, model: MotionModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The commands as the robot executed them: times shifted by the lag, speeds scaled.

    Returns ``(start_s (N,), v (N,), w (N,))``; command ``i`` holds from
    ``start_s[i]`` to ``start_s[i + 1]`` (the last one until the end of the log).
    """
    return (
        np.asarray(times_s, dtype=np.float64) + model.lag_s,
        np.asarray(v_mps, dtype=np.float64) * model.forward_scale,
        np.asarray(w_radps, dtype=np.float64) * model.angular_scale,
    )


def integrate(
    start_s: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    frame_times_s: np.ndarray,
    coefficients: tuple[float, ...],
) -> tuple[np.ndarray, np.ndarray]:
    """Relative motion and its covariance between consecutive frame times.

    Args:
        start_s, v, w: (N,) held commands (:func:`held_commands`), ``start_s``
            non-decreasing. Before ``start_s[0]`` the robot stands still.
        frame_times_s: (F,) non-decreasing frame times.
        coefficients: the noise model's six coefficients (:class:`MotionModel`).

    Returns:
        ``deltas (F-1, 3)``: ``[dx_m, dy_m, dtheta_rad]`` of frame ``k+1`` in the
        frame of ``k``; ``covariances (F-1, 3, 3)`` (without
        :data:`COVARIANCE_FLOOR`, which the reader adds).
    """
    # Pure-Python floats: one small step per command (60k a robot), where numpy's
    # per-call cost would dominate.
    a_s, b_s, a_y, a_th, c_th, b_th = (float(c) for c in coefficients)
    starts = start_s.tolist()
    vs, ws = v.tolist(), w.tolist()
    n = len(starts)
    times = np.asarray(frame_times_s, dtype=np.float64).tolist()
    deltas = np.zeros((max(len(times) - 1, 0), 3))
    covs = np.zeros((max(len(times) - 1, 0), 3, 3))
    i = int(np.searchsorted(start_s, times[0], side="right")) - 1 if times else 0
    for k in range(len(times) - 1):
        t, t_end = times[k], times[k + 1]
        x = y = th = 0.0
        sxx = sxy = sxt = syy = syt = stt = 0.0
        while t < t_end:
            while i + 1 < n and starts[i + 1] <= t:
                i += 1
            nxt = starts[i + 1] if i + 1 < n else math.inf
            if i < 0:  # before the first command: standing still
                nxt = starts[0] if n else math.inf
            seg_end = min(nxt, t_end)
            dt = seg_end - t
            t = seg_end
            if dt <= 0.0 or i < 0:
                continue
            ds, dth = vs[i] * dt, ws[i] * dt
            if abs(dth) > 1e-12:
                r = ds / dth
                lx, ly = r * math.sin(dth), r * (1.0 - math.cos(dth))
            else:
                lx, ly = ds, 0.0
            c, s = math.cos(th), math.sin(th)
            mx, my = c * lx - s * ly, s * lx + c * ly
            # F Sigma F^T with F = [[1, 0, -my], [0, 1, mx], [0, 0, 1]]
            sxx, sxy, sxt, syy, syt = (
                sxx - 2 * my * sxt + my * my * stt,
                sxy + mx * sxt - my * syt - my * mx * stt,
                sxt - my * stt,
                syy + 2 * mx * syt + mx * mx * stt,
                syt + mx * stt,
            )
            # + G Q G^T, Q diagonal in the interval's mid-heading frame
            q_al = a_s * abs(ds) + b_s * dt
            q_la = a_y * abs(ds)
            q_th = a_th * abs(dth) + c_th * abs(ds) + b_th * dt
            phi = th + 0.5 * dth
            cp, sp = math.cos(phi), math.sin(phi)
            sxx += cp * cp * q_al + sp * sp * q_la
            sxy += cp * sp * (q_al - q_la)
            syy += sp * sp * q_al + cp * cp * q_la
            stt += q_th
            x, y, th = x + mx, y + my, th + dth
        deltas[k] = (x, y, math.remainder(th, 2 * math.pi))
        covs[k] = ((sxx, sxy, sxt), (sxy, syy, syt), (sxt, syt, stt))
    return deltas, covs
