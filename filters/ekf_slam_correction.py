"""One observation's correction of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`).

:class:`EkfCorrection` holds the update of the filter's state by one
range-bearing observation of a mapped landmark: its Jacobian (standard or
observability-constrained, Huang, Mourikis & Roumeliotis, IJRR 2010), the
float64 noise floor of :mod:`filters.numerics`, the plain rank-2 update and,
for innovations beyond ``damped_update_nis``, the damped iterated step of
:mod:`filters.ekf_slam_update`. Every safeguard that acts is counted in
``self.recoveries``. The class is a mixin: it reads the filter's buffers
(``_xbuf``, ``_Pbuf``, ``_n``, ``_x_pred``, ``_m_first``) and ``config``.
"""

from __future__ import annotations

import math

import numpy as np

from filters.ekf_slam_update import (
    APPLIED, INDEFINITE, damped_iterated_step, nis_2x2, rank2_correction,
)
from filters.numerics import CHI2_2DOF_999, floored_noise, symmetrise
from slamcore.planar import geometry as models
from slamcore.planar.geometry import wrap_angle

#: Largest ``tr(R^-1 dH P dH^T)`` for which an update keeps the OC Jacobian
#: (:meth:`EkfCorrection._prior_jacobian`): the chi-square 0.999 quantile, 2 dof, as
#: the association gate. Course noise, seeds 0-2: at most 7.4 (99 % below 2.2).
OC_SPREAD_LIMIT = CHI2_2DOF_999


class EkfCorrection:
    """Mixin of :class:`filters.ekf_slam.EkfSlam`: the update by one observation."""

    def _kalman_update(self, slot: int, z: np.ndarray, R: np.ndarray,
                       gate: float = math.inf) -> bool:
        """One sequential EKF update with the landmark in ``slot`` (see module docstring).

        Returns False, leaving the state untouched, when the innovation's squared
        Mahalanobis distance exceeds ``gate``, or when its covariance is not
        positive definite (counted as a ``skipped_update`` recovery). An
        innovation beyond ``damped_update_nis`` takes the damped iterated step
        (:func:`filters.ekf_slam_update.damped_iterated_step`).
        """
        n = self._n
        i = 3 + 2 * slot
        x = self._xbuf
        P = self._Pbuf[:n, :n]
        J = [0, 1, 2, i, i + 1]
        oc, H = self._prior_jacobian(slot, x[J], P[np.ix_(J, J)], R)
        R = self._floored(R, H, P)
        HP = H[:, :3] @ P[0:3] + H[:, 3:] @ P[i:i + 2]  # (2, n): H P, from contiguous rows
        S = symmetrise(HP[:, 0:3] @ H[:, :3].T + HP[:, i:i + 2] @ H[:, 3:].T + R)  # (2, 2)
        nu = models.innovation(z, models.observe(x[:3], x[i:i + 2]))
        limit = self.config.damped_update_nis
        nis = nis_2x2(S, nu)
        damped = limit is not None and limit < nis <= gate  # nis is inf if S is indefinite
        if damped:
            a = damped_iterated_step(x[J].copy(), P[np.ix_(J, J)], z, R,
                                     lambda xJ: self._jacobian(slot, xJ, oc))
            if a is None:
                damped = False
        if not damped:
            outcome = rank2_correction(x[:n], P, HP, S, nu, gate)
        else:
            x[:n] += P[:, J] @ a  # the iterate; the covariance is linearised there (IEKF)
            H = self._jacobian(slot, x[J], oc)
            HP = H[:, :3] @ P[0:3] + H[:, 3:] @ P[i:i + 2]
            S = symmetrise(HP[:, 0:3] @ H[:, :3].T + HP[:, i:i + 2] @ H[:, 3:].T + R)
            outcome = rank2_correction(x[:n], P, HP, S, nu, move_state=False)
            self.recoveries.add("damped_update")
        if outcome == INDEFINITE:
            self.recoveries.add("skipped_update")
        if outcome != APPLIED:
            return False
        x[2] = wrap_angle(x[2])
        return True

    def _jacobian(self, slot: int, xJ: np.ndarray, oc: bool) -> np.ndarray:
        """(2, 5) observation Jacobian over robot and landmark at ``xJ`` (OC-projected if ``oc``)."""
        H_x, H_m = models.observe_jacobians(xJ[:3], xJ[3:5])
        if oc:
            H_x, H_m = self._observability_constrained(slot, H_x, H_m)
        return np.hstack([H_x, H_m])

    def _prior_jacobian(self, slot: int, xJ: np.ndarray, PJ: np.ndarray,
                        R: np.ndarray) -> tuple[bool, np.ndarray]:
        """Whether this update uses the OC Jacobian (``jacobians = "oc"``), and H at ``xJ``.

        The projection moves ``H`` by ``dH``, through the landmark's first
        estimate; the error that makes in the predicted measurement over the
        state's spread has covariance ``dH P dH^T``. Beyond the measurement
        noise (``tr(R^-1 dH P dH^T)`` above :data:`OC_SPREAD_LIMIT`) the
        projected Jacobian is no longer a linearisation of this measurement:
        with precise ranges (``sigma_r_m = 1 mm`` against 10 deg bearings, first
        estimates a metre off laterally; median 256-1500) it drove the filter to
        1e100 m. Then the update takes the standard Jacobian (counted as
        ``oc_fallback``).
        """
        H_x, H_m = models.observe_jacobians(xJ[:3], xJ[3:5])
        H = np.hstack([H_x, H_m])
        if self.config.jacobians != "oc":
            return False, H
        H_oc = np.hstack(self._observability_constrained(slot, H_x, H_m))
        dH = H_oc - H
        spread = np.trace(np.linalg.solve(R, dH @ PJ @ dH.T))
        if spread <= OC_SPREAD_LIMIT:  # False for NaN too
            return True, H_oc
        self.recoveries.add("oc_fallback")
        return False, H

    def _floored(self, R: np.ndarray, H: np.ndarray, P: np.ndarray) -> np.ndarray:
        """``R`` raised to the float64 floor of :mod:`filters.numerics` (counted when it acts)."""
        pmax = float(np.max(np.diagonal(P)))
        R, hit = floored_noise(R, pmax * np.einsum("ij,ij->i", H, H))
        if hit:
            self.recoveries.add("noise_floor")
        return R

    def _observability_constrained(self, slot: int, H_x: np.ndarray, H_m: np.ndarray):
        """The Jacobian nearest to ``[H_x H_m]`` that keeps global rotation unobservable.

        OC-EKF (Huang, Mourikis & Roumeliotis, IJRR 2010): the plain EKF
        linearises at estimates that move over time, which hands it information
        about the global heading that no measurement carries, and it becomes
        overconfident. The unobservable directions (translation, and rotation
        about the origin) are tracked at the robot's predicted positions and the
        landmark's first estimate; ``H`` is projected onto their complement.
        """
        px, py = self._x_pred[0], self._x_pred[1]
        mx, my = self._m_first[slot]
        N = np.array([[1.0, 0.0, -py], [0.0, 1.0, px], [0.0, 0.0, 1.0],
                      [1.0, 0.0, -my], [0.0, 1.0, mx]])
        H = np.hstack([H_x, H_m])
        try:
            H = H - (H @ N) @ np.linalg.solve(N.T @ N, N.T)
        except np.linalg.LinAlgError:
            # N has full column rank (rows 1-3 are [I | p]); only a state at
            # ~1e8 m makes N^T N numerically singular, and lstsq stays defined
            H = H - (H @ N) @ np.linalg.lstsq(N, np.eye(5), rcond=None)[0]
        return H[:, :3], H[:, 3:]
