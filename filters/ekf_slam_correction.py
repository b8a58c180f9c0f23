"""One observation's correction of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`).

:func:`kalman_update` updates the state held in a
:class:`filters.ekf_slam_store.SlotStore` by one range-bearing observation of
a mapped landmark: its Jacobian (standard or observability-constrained, Huang,
Mourikis & Roumeliotis, IJRR 2010), the float64 noise floor of
:mod:`filters.numerics`, the plain rank-2 update and, for innovations beyond
``damped_update_nis``, the damped iterated step of
:mod:`filters.ekf_slam_update`. These functions own no state: they take the
store, the filter's settings and the :class:`filters.numerics.Recoveries` in
which every safeguard that acts is counted as arguments, and change only
those. They are apart from the filter because they are the numerics of one
update (Jacobians, safeguards), which the filter's bookkeeping (pose history,
association, provisional list) never needs to see.
"""

from __future__ import annotations

import math

import numpy as np

from filters.ekf_slam_config import EkfSlamConfig
from filters.ekf_slam_store import SlotStore
from filters.ekf_slam_update import APPLIED, INDEFINITE, damped_iterated_step, rank2_correction
from filters.numerics import CHI2_2DOF_999, REL_VARIANCE_FLOOR, Recoveries, floored_noise

#: Largest ``tr(R^-1 dH P dH^T)`` for which an update keeps the OC Jacobian
#: (:func:`_choose_jacobian`): the chi-square 0.999 quantile, 2 dof, as
#: the association gate. Course noise, seeds 0-2: at most 7.4 (99 % below 2.2).
OC_SPREAD_LIMIT = CHI2_2DOF_999

_PI, _TWO_PI = math.pi, 2.0 * math.pi


def _wrap(a: float) -> float:
    """:func:`slamcore.planar.geometry.wrap_angle` on a float (same formula, same bits)."""
    return (a + _PI) % _TWO_PI - _PI


def range_bearing(xr: list[float], m: list[float]):
    """Predicted ``(range, bearing)`` of landmark ``m`` from pose ``xr`` and the two rows
    of its Jacobian over (x, y, theta, mx, my), as floats (the formulas of
    :func:`slamcore.planar.geometry.observe` and ``observe_jacobians``); None when
    the landmark sits on the robot or the numbers are not finite."""
    dx, dy = m[0] - xr[0], m[1] - xr[1]
    q = dx * dx + dy * dy
    if not (0.0 < q < math.inf):
        return None
    r = math.sqrt(q)
    h0 = (-(dx / r), -(dy / r), 0.0, dx / r, dy / r)
    h1 = (-(-dy / q), -(dx / q), -1.0, -dy / q, dx / q)
    return math.hypot(dx, dy), _wrap(math.atan2(dy, dx) - xr[2]), (h0, h1)


def oc_project(h0, h1, p: list[float], f: list[float]):
    """Rows ``h0``, ``h1`` (5 floats each) projected onto the complement of the unobservable
    directions tracked at robot position ``p`` and landmark first estimate ``f``;
    returns the two projected rows and the two rows of ``dH`` = projected - given,
    flat (20 floats, row after row).

    Those directions are the two translations ``e_x = (1,0,0,1,0)``,
    ``e_y = (0,1,0,0,1)`` and the rotation about the origin; taken about the
    midpoint of ``p`` and ``f`` instead (same span: it differs by a
    translation) the rotation is ``r = (-ey, ex, 1, ey, -ex)`` with ``(ex, ey) =
    (p - f) / 2``, orthogonal to both translations, so the projection is three
    independent dot products, with no 3x3 solve and no loss of digits far from
    the origin.
    """
    ex, ey = 0.5 * (p[0] - f[0]), 0.5 * (p[1] - f[1])
    rr = 1.0 + 2.0 * (ex * ex + ey * ey)  # |r|^2
    a0, a1, a2, a3, a4 = h0
    tx, ty = -0.5 * (a0 + a3), -0.5 * (a1 + a4)
    t = -(-ey * a0 + ex * a1 + a2 + ey * a3 - ex * a4) / rr
    d0 = (tx - t * ey, ty + t * ex, t, tx + t * ey, ty - t * ex)
    b0, b1, b2, b3, b4 = h1
    tx, ty = -0.5 * (b0 + b3), -0.5 * (b1 + b4)
    t = -(-ey * b0 + ex * b1 + b2 + ey * b3 - ex * b4) / rr
    d1 = (tx - t * ey, ty + t * ex, t, tx + t * ey, ty - t * ex)
    return (
        (
            a0 + d0[0],
            a1 + d0[1],
            a2 + d0[2],
            a3 + d0[3],
            a4 + d0[4],
            b0 + d1[0],
            b1 + d1[1],
            b2 + d1[2],
            b3 + d1[3],
            b4 + d1[4],
        )
        + d0
        + d1
    )


def kalman_update(
    st: SlotStore,
    slot: int,
    z: np.ndarray,
    R: np.ndarray,
    config: EkfSlamConfig,
    recoveries: Recoveries,
    gate: float = math.inf,
) -> bool:
    """One sequential EKF update of ``st`` with the landmark in ``slot``
    (:mod:`filters.ekf_slam`'s docstring); ``config`` gives ``jacobians`` and
    ``damped_update_nis``, ``recoveries`` counts the safeguards that act.

    Returns False, leaving the state untouched, when the innovation's squared
    Mahalanobis distance exceeds ``gate``, or when its covariance is not
    positive definite (counted as a ``skipped_update`` recovery). An
    innovation beyond ``damped_update_nis`` takes the damped iterated step
    (:func:`filters.ekf_slam_update.damped_iterated_step`).
    """
    n, i, x = st.n, 3 + 2 * slot, st.xbuf
    pred = range_bearing(x[:3].tolist(), x[i : i + 2].tolist())
    if pred is None:
        recoveries.add("skipped_update")
        return False
    J = np.array((0, 1, 2, i, i + 1))
    rows = st.Pbuf.take(J, axis=0)  # P[J, :] (symmetric P: the columns J too)
    PJ = rows.take(J, axis=1)
    Rl = R.tolist()
    oc, H, HPH = _choose_jacobian(st, slot, pred[2], PJ, Rl, config.jacobians == "oc", recoveries)
    Rf = _floored(st, R, Rl, H, recoveries)
    if Rf is not R:
        R, Rl = Rf, Rf.tolist()
    S = _innovation_cov(HPH, Rl)
    z0, z1 = z.tolist()
    nu = (z0 - pred[0], _wrap(z1 - pred[1]))
    limit = config.damped_update_nis
    if limit is not None and limit < _nis(S, nu) <= gate:  # _nis is inf if S is indefinite
        outcome = _damped_update(st, slot, J, rows, PJ, z, R, oc, nu, H, S, recoveries)
    else:
        outcome = rank2_correction(x, n, rows, H, S, nu, st.downdate, gate)
    if outcome == INDEFINITE:
        recoveries.add("skipped_update")
    if outcome != APPLIED:
        return False
    x[2] = _wrap(float(x[2]))
    return True


def _damped_update(st: SlotStore, slot, J, rows, PJ, z, R, oc, nu, H, S, recoveries: Recoveries) -> str:
    """The damped iterated step, then the covariance linearised at its iterate (IEKF);
    the plain correction (``H``, ``S``) when no step decreases the MAP cost."""
    n, x = st.n, st.xbuf
    a = damped_iterated_step(x[J].copy(), PJ, z, R, lambda xJ: _jacobian(st, slot, xJ, oc))
    if a is None:
        return rank2_correction(x, n, rows, H, S, nu, st.downdate)
    x[:n] += a @ rows[:, :n]  # the iterate x0 + P[:, J] a (P symmetric)
    H, HPH = _with_jacobian(_jacobian(st, slot, x[J], oc), PJ)
    recoveries.add("damped_update")
    return rank2_correction(
        x, n, rows, H, _innovation_cov(HPH, R.tolist()), nu, st.downdate, move_state=False
    )


def _with_jacobian(H: np.ndarray, PJ: np.ndarray):
    """``H`` (2, 5) as two tuples of floats, and ``H P_JJ H^T`` as nested lists."""
    return tuple(map(tuple, H.tolist())), H.dot(PJ).dot(H.T).tolist()


def _jacobian(st: SlotStore, slot: int, xJ: np.ndarray, oc: bool) -> np.ndarray:
    """(2, 5) observation Jacobian over robot and landmark at ``xJ`` (OC-projected if ``oc``)."""
    xl = xJ.tolist()
    pred = range_bearing(xl[:3], xl[3:5])
    h = pred[2] if pred is not None else ((math.nan,) * 5,) * 2
    if oc:
        return np.array(_oc_rows(st, slot, h)[:10]).reshape(2, 5)
    return np.array(h)


def _oc_rows(st: SlotStore, slot: int, h):
    """:func:`oc_project` of ``h`` at the predicted pose and the landmark's first estimate."""
    return oc_project(h[0], h[1], st.x_pred.tolist(), st.m_first[slot].tolist())


def _choose_jacobian(st: SlotStore, slot: int, h, PJ: np.ndarray, Rl: list, oc: bool, recoveries: Recoveries):
    """Whether this update uses the OC Jacobian (asked by ``oc``), ``H`` (two rows of
    floats) and ``H P_JJ H^T`` (nested lists); ``Rl`` is R as nested lists.

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
    if oc:
        G = _oc_rows(st, slot, h)  # H_oc (2 rows), dH (2 rows), flat
        Ga = np.array(G).reshape(4, 5)
        Q = Ga.dot(PJ).dot(Ga.T).tolist()  # [[H PJ H^T, .], [., dH PJ dH^T]]
        (r00, r01), (r10, r11) = Rl
        det = r00 * r11 - r01 * r10
        spread = math.inf
        if det > 0.0:  # tr(R^-1 D), D = dH PJ dH^T
            spread = (r11 * Q[2][2] - r01 * Q[3][2] - r10 * Q[2][3] + r00 * Q[3][3]) / det
        if spread <= OC_SPREAD_LIMIT:  # False for NaN too
            return True, (G[:5], G[5:10]), (Q[0][:2], Q[1][:2])
        recoveries.add("oc_fallback")
    Ha = np.array(h)
    return False, h, Ha.dot(PJ).dot(Ha.T).tolist()


def _floored(st: SlotStore, R: np.ndarray, Rl: list, H, recoveries: Recoveries) -> np.ndarray:
    """``R`` raised to the float64 floor of :mod:`filters.numerics` (counted when it acts).

    The floor scales with P's largest variance. ``st.pmax_ub`` bounds it from
    above (a downdate only lowers variances; the filter raises the bound
    where it raises one), so the O(n) maximum is taken only when the floor
    might act.
    """
    (h0, h1) = H
    g0 = h0[0] * h0[0] + h0[1] * h0[1] + h0[2] * h0[2] + h0[3] * h0[3] + h0[4] * h0[4]
    g1 = h1[0] * h1[0] + h1[1] * h1[1] + h1[2] * h1[2] + h1[3] * h1[3] + h1[4] * h1[4]
    r00, r11 = Rl[0][0], Rl[1][1]
    ub = st.pmax_ub * REL_VARIANCE_FLOOR
    if not (r00 < ub * g0 or r11 < ub * g1):
        return R
    pmax = float(st.diag.max())  # the diagonal beyond n is zero
    st.pmax_ub = pmax
    v0, v1 = pmax * g0, pmax * g1
    if not (r00 < REL_VARIANCE_FLOOR * v0 or r11 < REL_VARIANCE_FLOOR * v1):
        return R  # floored_noise's test, without its arrays
    R, hit = floored_noise(R, np.array([v0, v1]))
    if hit:
        recoveries.add("noise_floor")
    return R


def observability_constrained(st: SlotStore, slot: int, H_x: np.ndarray, H_m: np.ndarray):
    """The Jacobian nearest to ``[H_x H_m]`` (landmark in ``slot``) that keeps global
    rotation unobservable, as ``(H_x, H_m)``.

    OC-EKF (Huang, Mourikis & Roumeliotis, IJRR 2010): the plain EKF
    linearises at estimates that move over time, which hands it information
    about the global heading that no measurement carries, and it becomes
    overconfident. The unobservable directions (translation, and rotation
    about the origin) are tracked at the robot's predicted positions and the
    landmark's first estimate (``st.x_pred``, ``st.m_first``); ``H`` is
    projected onto their complement (:func:`oc_project`).
    """
    H = np.array(_oc_rows(st, slot, np.hstack([H_x, H_m]).tolist())[:10]).reshape(2, 5)
    return H[:, :3], H[:, 3:]


def _nis(S: tuple[float, float, float], nu: tuple[float, float]) -> float:
    """``nu^T S^-1 nu`` for ``S = (s00, s01, s11)``; inf when S is not positive definite."""
    s00, s01, s11 = S
    det = s00 * s11 - s01 * s01
    if not (s00 > 0.0 and det > 0.0 and det < math.inf):
        return math.inf
    return (s11 * nu[0] * nu[0] - 2.0 * s01 * nu[0] * nu[1] + s00 * nu[1] * nu[1]) / det


def _innovation_cov(HPH, Rl: list) -> tuple[float, float, float]:
    """``H P H^T + R`` symmetrised, as ``(s00, s01, s11)``."""
    (r00, r01), (r10, r11) = Rl
    return HPH[0][0] + r00, 0.5 * ((HPH[0][1] + r01) + (HPH[1][0] + r10)), HPH[1][1] + r11


def pose_sighting_update(st: SlotStore, i: int, j: int, z: np.ndarray, R: np.ndarray, gate: float) -> bool:
    """One EKF correction of ``st`` by the range and bearing ``z`` (2,) (covariance ``R``)
    of the pose at state index ``j`` seen from the pose at index ``i`` (several robots,
    :mod:`filters.ekf_slam`), with the standard Jacobian.

    Written plainly (O(n^2) numpy over the whole ``P``): robots see each other a few
    hundred times a run, against the landmark correction's thousands, which
    :func:`kalman_update` makes fast. The OC projection is not applied: it is made
    for the robot-landmark pair of that update. Returns False, leaving the state
    untouched, when the squared Mahalanobis distance of the innovation exceeds
    ``gate`` or its covariance is not positive definite.
    """
    n, x, P = st.n, st.xbuf, st.Pbuf
    pred = range_bearing(x[i : i + 3].tolist(), x[j : j + 2].tolist())
    if pred is None:
        return False
    h = np.array(pred[2])  # (2, 5) over (x_i, y_i, theta_i, x_j, y_j)
    J = np.array((i, i + 1, i + 2, j, j + 1))
    PJ = P[J, :n]  # (5, n): P[:, J] transposed (P is symmetric)
    HP = h @ PJ  # (2, n)
    S = HP[:, J] @ h.T + np.asarray(R, float)
    S = 0.5 * (S + S.T)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return False
    nu = np.array((z[0] - pred[0], _wrap(float(z[1]) - pred[1])))
    w = np.linalg.solve(L, nu)
    if float(w @ w) > gate:
        return False
    M = np.linalg.solve(L, HP)  # (2, n): P -= M^T M, x += M^T w
    x[:n] += M.T @ w
    for k in (i + 2, j + 2):  # both headings move (the seen one through P)
        x[k] = _wrap(float(x[k]))
    P[:n, :n] -= M.T @ M
    P[:n, :n] = 0.5 * (P[:n, :n] + P[:n, :n].T)
    return True
