"""One sequential EKF correction with a 2-D measurement, as an in-place rank-2 downdate.

With ``H P`` (2, n) and ``S = H P H^T + R`` (2, 2), the state moves by
``(H P)^T S^-1 nu`` and the covariance loses ``(H P)^T S^-1 (H P) = M M^T``
with ``M = (L^-1 H P)^T`` (n, 2), ``S = L L^T``. ``P -= M M^T`` is applied in
place one block of rows at a time (:data:`ROW_BLOCK_ELEMENTS`), so no n x n
temporary is built; each entry (i, j) and (j, i) is the same two products
summed in the same order, so ``P`` stays symmetric. O(n^2), nothing O(n^3).

:func:`damped_iterated_step` is the update for innovations the linearisation
cannot be trusted with: the iterated EKF is Gauss-Newton on the MAP cost
``V = 1/2 |x - x0|^2_{P^-1} + 1/2 |z - h(x)|^2_{R^-1}``, and damping it with a
backtracking line search on ``V`` (Skoglund, Hendeby & Axehill, "Extended
Kalman filter modifications based on an optimization view point", FUSION
2015) makes every accepted step decrease that cost, where the plain EKF step
can overshoot by tens of metres (100 deg bearing noise, or a 2 cm range after a
long loop). ``h`` involves only the robot and one landmark, and every iterate
is ``x0 + P J^T a`` with ``a`` supported on those 5 entries ``J``, so the whole
search runs on 5-vectors: ``|x - x0|^2_{P^-1} = a^T P_JJ a``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from slamcore.planar import geometry as models

#: Size of one block of the in-place rank-2 downdate, in doubles (1 MiB): the
#: block has ``clip(ROW_BLOCK_ELEMENTS // n, 8, 64)`` rows of P. Small blocks keep
#: the temporary in cache and keep OpenBLAS on one thread for each small gemm
#: (measured: 128-row blocks at n = 4003 went multithreaded and ran 15x slower
#: on a loaded machine).
ROW_BLOCK_ELEMENTS = 1 << 17

#: :func:`rank2_correction` outcomes.
APPLIED, GATED, INDEFINITE = "applied", "gated", "indefinite"

#: Gauss-Newton iterations and step halvings of :func:`damped_iterated_step`.
MAX_ITERATIONS = 20
MAX_HALVINGS = 30
#: Relative decrease of the MAP cost below which the iteration has converged.
COST_TOLERANCE = 1e-10


def cholesky_2x2(S: np.ndarray) -> tuple[float, float, float] | None:
    """``S = L L^T`` with ``L = [[a, 0], [b, c]]``; None unless S is finite positive definite."""
    s00 = float(S[0, 0])
    if not (s00 > 0.0 and math.isfinite(s00)):
        return None
    a = math.sqrt(s00)
    b = float(S[1, 0]) / a
    c2 = float(S[1, 1]) - b * b
    if not (c2 > 0.0 and math.isfinite(c2)):
        return None
    return a, b, math.sqrt(c2)


def rank2_correction(x: np.ndarray, P: np.ndarray, HP: np.ndarray, S: np.ndarray,
                     nu: np.ndarray, gate: float = math.inf, move_state: bool = True) -> str:
    """Correct ``x`` (n,) and ``P`` (n, n) in place with ``H P`` (2, n), ``S`` (2, 2)
    and the innovation ``nu`` (2,).

    Returns :data:`GATED` when ``nu^T S^-1 nu`` exceeds ``gate`` and
    :data:`INDEFINITE` when ``S`` is not positive definite (both leave ``x``
    and ``P`` untouched), else :data:`APPLIED`. ``move_state=False`` applies
    only the covariance downdate (the caller moved the state). Angles in
    ``x`` are not wrapped here.
    """
    chol = cholesky_2x2(S)
    if chol is None:
        return INDEFINITE
    a, b, c = chol
    n = len(x)
    # L^-1 = [[1/a, 0], [-b/(a c), 1/c]]
    Mt = np.empty((2, n))
    np.multiply(HP[0], 1.0 / a, out=Mt[0])
    np.multiply(HP[1], 1.0 / c, out=Mt[1])
    Mt[1] -= (b / (a * c)) * HP[0]
    # w = L^-1 nu; state += (H P)^T S^-1 nu = M (L^-1 nu)
    w0 = nu[0] / a
    w1 = (nu[1] - b * w0) / c
    if w0 * w0 + w1 * w1 > gate:  # |L^-1 nu|^2 = nu^T S^-1 nu
        return GATED
    if move_state:
        x += Mt[0] * w0 + Mt[1] * w1
    # P -= M M^T, in place, one block of rows at a time.
    M = Mt.T  # (n, 2) view
    rows = min(64, max(8, ROW_BLOCK_ELEMENTS // n))
    if n <= 2 * rows:
        np.subtract(P, M @ Mt, out=P)
    else:
        for r0 in range(0, n, rows):
            blk = P[r0:r0 + rows]
            np.subtract(blk, M[r0:r0 + rows] @ Mt, out=blk)
    return APPLIED


def map_cost(a: np.ndarray, x0J: np.ndarray, PJ: np.ndarray, z: np.ndarray,
             Rinv: np.ndarray) -> tuple[float, np.ndarray]:
    """MAP cost ``V`` at ``x_J = x0_J + P_JJ a`` (robot 3 + landmark 2), and that ``x_J``."""
    dx = PJ @ a
    xJ = x0J + dx
    r = models.innovation(z, models.observe(xJ[:3], xJ[3:5]))
    return 0.5 * float(a @ dx) + 0.5 * float(r @ Rinv @ r), xJ


def damped_iterated_step(x0J: np.ndarray, PJ: np.ndarray, z: np.ndarray, R: np.ndarray,
                         jacobian: Callable[[np.ndarray], np.ndarray]) -> np.ndarray | None:
    """Damped iterated EKF over the 5 entries ``J`` (robot, landmark): the ``a`` (5,) with
    ``x = x0 + P[:, J] a``, or None when no step decreases the MAP cost.

    Args:
        x0J: (5,) prior robot pose and landmark; PJ: (5, 5) their covariance.
        z, R: the measurement (2,) and its covariance (2, 2).
        jacobian: ``x_J -> H`` (2, 5), the observation Jacobian at an iterate.
    """
    Rinv = np.linalg.inv(R)
    a = np.zeros(5)
    cost, xJ = map_cost(a, x0J, PJ, z, Rinv)
    moved = False
    for _ in range(MAX_ITERATIONS):
        H = jacobian(xJ)
        S = H @ PJ @ H.T + R
        if cholesky_2x2(S) is None:
            break
        r = models.innovation(z, models.observe(xJ[:3], xJ[3:5]))
        # IEKF: x+ = x0 + K (z - h(x) - H (x0 - x)), K = P H^T S^-1
        step = H.T @ np.linalg.solve(S, r + H @ (xJ - x0J)) - a
        alpha = 1.0
        for _ in range(MAX_HALVINGS):
            trial_cost, trial_x = map_cost(a + alpha * step, x0J, PJ, z, Rinv)
            if trial_cost < cost:
                break
            alpha *= 0.5
        else:
            break
        a = a + alpha * step
        decrease = cost - trial_cost
        cost, xJ, moved = trial_cost, trial_x, True
        if decrease <= COST_TOLERANCE * max(cost, 1.0):
            break
    return a if moved else None


def nis_2x2(S: np.ndarray, nu: np.ndarray) -> float:
    """``nu^T S^-1 nu`` for a 2x2 ``S``; inf when S is not positive definite."""
    chol = cholesky_2x2(S)
    if chol is None:
        return math.inf
    a, b, c = chol
    w0 = nu[0] / a
    w1 = (nu[1] - b * w0) / c
    return w0 * w0 + w1 * w1
