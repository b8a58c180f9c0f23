"""The fast EKF-SLAM update (issue 20 item 3) equals the textbook update written out densely.

The reference below is the plain formula on the full state: the dense 2 x n
Jacobian, its observability-constrained projection by the 3x3 solve of Huang,
Mourikis & Roumeliotis (IJRR 2010) with the unobservable directions at the
predicted pose and the landmark's first estimate, ``S = H P H^T + R``,
``K = P H^T S^-1``, ``x += K nu`` and ``P -= K S K^T``. It shares nothing with
the filter's code but :mod:`slamcore.planar.geometry`'s measurement model.
"""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from filters.ekf_slam import EkfSlam
from filters.ekf_slam_config import EkfSlamConfig
from filters.ekf_slam_update import Rank2Downdate
from slamcore.planar import geometry as models
from slamcore.planar.geometry import wrap_angle
from slamcore.planar.records import Observation, Odometry

#: State agreement after a sequence of updates: metres (positions), radians (heading).
STATE_TOL_M = 1e-9
#: Covariance agreement, in the state's units squared (variances about 1e-2 to 1).
COV_TOL = 1e-11
R_OBS = np.diag([0.04, 0.003])


def _filter(rng, n_lm: int, capacity: int) -> EkfSlam:
    """A filter whose landmarks' first estimates and predicted pose differ from the state,
    so that the OC projection is not the identity; buffers larger than the state."""
    x = np.r_[rng.normal(size=2), rng.uniform(-np.pi, np.pi), rng.uniform(-15, 15, size=2 * n_lm)]
    B = rng.normal(size=(x.size, 6)) * 0.1
    P = B @ B.T + np.eye(x.size) * 0.02
    ekf = EkfSlam(EkfSlamConfig(initial_capacity=capacity))
    ekf.load_state(0, x, P)
    ekf.predict(Odometry(0, 1, np.array([0.5, 0.02, 0.05]), np.diag([1e-3, 1e-3, 1e-4])), 1)
    return ekf


def _reference_update(x, P, slot, z, R, x_pred, m_first, oc=True):
    """One EKF update, densely, with the OC Jacobian by the textbook projection."""
    n = x.size
    i = 3 + 2 * slot
    H_x, H_m = models.observe_jacobians(x[:3], x[i:i + 2])
    HJ = np.hstack([H_x, H_m])
    if oc:
        px, py = x_pred[:2]
        mx, my = m_first
        N = np.array([[1, 0, -py], [0, 1, px], [0, 0, 1], [1, 0, -my], [0, 1, mx]], dtype=float)
        HJ = HJ - HJ @ N @ np.linalg.solve(N.T @ N, N.T)
    H = np.zeros((2, n))
    H[:, :3], H[:, i:i + 2] = HJ[:, :3], HJ[:, 3:]
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    nu = models.innovation(z, models.observe(x[:3], x[i:i + 2]))
    x = x + K @ nu
    x[2] = wrap_angle(x[2])
    return x, P - K @ S @ K.T


@pytest.mark.parametrize("n_lm, capacity", [(4, 16), (60, 64), (120, 97)])
def test_update_sequence_equals_the_dense_textbook_update(n_lm, capacity):
    rng = np.random.default_rng(n_lm)
    ekf = _filter(rng, n_lm, capacity)
    x, P = ekf.state_vector(), ekf.state_covariance()
    x_pred = ekf.current_pose()
    first = x[3:].reshape(n_lm, 2).copy()
    for slot in rng.integers(0, n_lm, size=12):
        i = 3 + 2 * slot
        z = models.observe(x[:3], x[i:i + 2]) + rng.normal(size=2) * np.sqrt(np.diag(R_OBS))
        ekf.update([Observation(1, int(slot), z, R_OBS)])
        x, P = _reference_update(x, P, slot, z, R_OBS, x_pred, first[slot])
    assert ekf.recoveries.total() == 0  # the common path only: no fallback took over
    d = ekf.state_vector() - x
    d[2] = wrap_angle(d[2])
    np.testing.assert_allclose(d, 0.0, atol=STATE_TOL_M)
    np.testing.assert_allclose(ekf.state_covariance(), P, atol=COV_TOL)


def test_standard_jacobians_equal_the_dense_textbook_update():
    rng = np.random.default_rng(5)
    x = np.r_[0.3, -0.2, 0.4, rng.uniform(-10, 10, size=2 * 30)]
    B = rng.normal(size=(x.size, 5)) * 0.1
    P = B @ B.T + np.eye(x.size) * 0.02
    ekf = EkfSlam(EkfSlamConfig(initial_capacity=40, jacobians="standard"))
    ekf.load_state(3, x, P)
    for slot in (7, 7, 22, 0):
        i = 3 + 2 * slot
        z = models.observe(x[:3], x[i:i + 2]) + np.array([0.1, -0.03])
        ekf.update([Observation(3, slot, z, R_OBS)])
        x, P = _reference_update(x, P, slot, z, R_OBS, None, None, oc=False)
    np.testing.assert_allclose(ekf.state_vector(), x, atol=STATE_TOL_M)
    np.testing.assert_allclose(ekf.state_covariance(), P, atol=COV_TOL)


@pytest.mark.parametrize("threads", [1, 2])  # one whole dgemm; single-threaded panels
@pytest.mark.parametrize("n", [13, 403, 1003, 1503])  # unpadded, 1003 and 1503 were asymmetric
def test_blas_downdate_is_the_numpy_one_and_keeps_p_symmetric_to_the_bit(n, threads):
    with threadpool_limits(threads):
        _check_downdate(n)


def _check_downdate(n: int) -> None:
    rng = np.random.default_rng(n)
    dim = -(-(n + 20) // 16) * 16
    P = np.zeros((dim, dim))
    B = rng.normal(size=(n, 4))
    P[:n, :n] = B @ B.T + np.eye(n)
    P_np = P.copy()
    m = -(-n // 16) * 16
    blas, plain = Rank2Downdate(P), Rank2Downdate(P_np, use_blas=False)
    for d in (blas, plain):
        d.W[:2, :n] = rng.normal(size=(2, n)) if d is blas else blas.W[:2, :n]
        d(m)
    Wn = blas.W[:2, :n]
    np.testing.assert_allclose(P[:n, :n], P_np[:n, :n], rtol=0, atol=1e-13)
    np.testing.assert_allclose(P[:n, :n], B @ B.T + np.eye(n) - Wn.T @ Wn, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(P, P.T)
    assert not P[n:].any() and not P[:, n:].any()  # the padding stays zero


def test_copied_and_pickled_filters_update_their_own_covariance():
    """The BLAS downdate holds raw buffer addresses: a deep copy or a pickle round trip
    must update its own P, leave the original's alone, and give the original's result."""
    import copy
    import pickle

    from filters.ekf_slam import EkfSlam
    from filters.ekf_slam_config import EkfSlamConfig
    from slamcore.planar import geometry as models
    from slamcore.planar.records import Observation

    rng = np.random.default_rng(7)
    n_lm = 20
    x = np.r_[0.0, 0.0, 0.1, rng.uniform(-20, 20, size=2 * n_lm)]
    B = rng.normal(size=(x.size, 6)) * 0.05
    P = B @ B.T + 0.01 * np.eye(x.size)
    ekf = EkfSlam(EkfSlamConfig(initial_capacity=n_lm))
    ekf.load_state(0, x, P)
    z = models.observe(x[:3], x[3 + 10:3 + 12]) + np.array([0.05, 0.01])
    obs = [Observation(0, 5, z, np.diag([0.04, 0.003]))]
    ekf.update([Observation(0, 3, models.observe(x[:3], x[3 + 6:3 + 8]), np.diag([0.04, 0.003]))])
    before = ekf._store.Pbuf.copy()  # the downdate's plans now hold this buffer's address
    twins = [copy.deepcopy(ekf), pickle.loads(pickle.dumps(ekf))]
    for twin in twins:
        twin.update(obs)
    assert np.array_equal(ekf._store.Pbuf, before)
    ekf.update(obs)
    for twin in twins:
        assert np.array_equal(twin._store.Pbuf, ekf._store.Pbuf) and np.array_equal(twin._store.xbuf, ekf._store.xbuf)
