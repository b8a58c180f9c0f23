"""One sequential EKF correction with a 2-D measurement, as an in-place rank-2 downdate.

With ``H P`` (2, n) and ``S = H P H^T + R`` (2, 2), the state moves by
``(H P)^T S^-1 nu`` and the covariance loses ``(H P)^T S^-1 (H P) = M M^T``
with ``M = (L^-1 H P)^T`` (n, 2), ``S = L L^T``. ``P -= M M^T`` is applied in
place one block of rows at a time (:data:`ROW_BLOCK_ELEMENTS`), so no n x n
temporary is built; each entry (i, j) and (j, i) is the same two products
summed in the same order, so ``P`` stays symmetric. O(n^2), nothing O(n^3).
"""

from __future__ import annotations

import math

import numpy as np

#: Size of one block of the in-place rank-2 downdate, in doubles (1 MiB): the
#: block has ``clip(ROW_BLOCK_ELEMENTS // n, 8, 64)`` rows of P. Small blocks keep
#: the temporary in cache and keep OpenBLAS on one thread for each small gemm
#: (measured: 128-row blocks at n = 4003 went multithreaded and ran 15x slower
#: on a loaded machine).
ROW_BLOCK_ELEMENTS = 1 << 17


def rank2_correction(x: np.ndarray, P: np.ndarray, HP: np.ndarray, S: np.ndarray,
                     nu: np.ndarray, gate: float = math.inf) -> bool:
    """Correct ``x`` (n,) and ``P`` (n, n) in place with ``H P`` (2, n), ``S`` (2, 2)
    (symmetric positive definite) and the innovation ``nu`` (2,).

    Returns False, leaving both untouched, when ``nu^T S^-1 nu`` exceeds
    ``gate``. Angles in ``x`` are not wrapped here.
    """
    n = len(x)
    # S = L L^T, L lower triangular 2x2, written out.
    a = math.sqrt(S[0, 0])
    b = S[1, 0] / a
    c = math.sqrt(S[1, 1] - b * b)
    # L^-1 = [[1/a, 0], [-b/(a c), 1/c]]
    Mt = np.empty((2, n))
    np.multiply(HP[0], 1.0 / a, out=Mt[0])
    np.multiply(HP[1], 1.0 / c, out=Mt[1])
    Mt[1] -= (b / (a * c)) * HP[0]
    # w = L^-1 nu; state += (H P)^T S^-1 nu = M (L^-1 nu)
    w0 = nu[0] / a
    w1 = (nu[1] - b * w0) / c
    if w0 * w0 + w1 * w1 > gate:  # |L^-1 nu|^2 = nu^T S^-1 nu
        return False
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
    return True
