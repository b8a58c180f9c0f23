"""2-D models: Jacobians against central differences, values against gtsam."""

import gtsam
import numpy as np
import pytest

from slamcore.planar import geometry as models

JAC_TOL = 1e-6  # absolute, on derivatives of metres/radians (step 1e-6)
VALUE_TOL = 1e-9  # metres / radians


def numeric_jacobian(f, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = eps
        d = f(x + dx) - f(x - dx)
        cols.append(d / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_compose_matches_gtsam(rng):
    for _ in range(20):
        a, b = rng.normal(size=3), rng.normal(size=3)
        expected = gtsam.Pose2(*a).compose(gtsam.Pose2(*b))
        got = models.compose(a, b)
        np.testing.assert_allclose(got, [expected.x(), expected.y(), expected.theta()], atol=VALUE_TOL)


def test_observe_matches_gtsam_bearing_range(rng):
    for _ in range(20):
        x, m = rng.normal(size=3), rng.normal(size=2) * 10
        pred = gtsam.BearingRange2D.Measure(gtsam.Pose2(*x), m)
        got = models.observe(x, m)
        assert got[0] == pytest.approx(pred.range(), abs=VALUE_TOL)
        assert got[1] == pytest.approx(pred.bearing().theta(), abs=VALUE_TOL)
        np.testing.assert_allclose(models.inverse_observe(x, got), m, atol=1e-9)


def test_jacobians_numeric(rng):
    x, u, m = rng.normal(size=3), rng.normal(size=3), rng.normal(size=2) * 5
    z = models.observe(x, m)
    J_x, J_u = models.compose_jacobians(x, u)
    np.testing.assert_allclose(J_x, numeric_jacobian(lambda v: models.compose(v, u), x), atol=JAC_TOL)
    np.testing.assert_allclose(J_u, numeric_jacobian(lambda v: models.compose(x, v), u), atol=JAC_TOL)
    H_x, H_m = models.observe_jacobians(x, m)
    np.testing.assert_allclose(H_x, numeric_jacobian(lambda v: models.observe(v, m), x), atol=JAC_TOL)
    np.testing.assert_allclose(H_m, numeric_jacobian(lambda v: models.observe(x, v), m), atol=JAC_TOL)
    G_x, G_z = models.inverse_observe_jacobians(x, z)
    np.testing.assert_allclose(G_x, numeric_jacobian(lambda v: models.inverse_observe(v, z), x), atol=JAC_TOL)
    np.testing.assert_allclose(G_z, numeric_jacobian(lambda v: models.inverse_observe(x, v), z), atol=JAC_TOL)


def test_batched_equals_single(rng):
    X, M = rng.normal(size=(5, 3)), rng.normal(size=(5, 2)) * 5
    Hx, Hm = models.observe_jacobians(X, M)
    for i in range(5):
        hx, hm = models.observe_jacobians(X[i], M[i])
        np.testing.assert_allclose(Hx[i], hx)
        np.testing.assert_allclose(Hm[i], hm)


def test_invert_matches_gtsam_and_propagates_through_its_jacobian(rng):
    for _ in range(10):
        u = rng.normal(size=3)
        A = rng.normal(size=(3, 3))
        Q = A @ A.T + 0.1 * np.eye(3)
        inv, Q_inv = models.invert(u, Q)
        expected = gtsam.Pose2(*u).inverse()
        np.testing.assert_allclose(inv, [expected.x(), expected.y(), expected.theta()],
                                   atol=VALUE_TOL)
        J = numeric_jacobian(lambda v: models.invert(v, Q)[0], u)
        np.testing.assert_allclose(Q_inv, J @ Q @ J.T, atol=JAC_TOL)
