"""One sequential EKF correction with a 2-D measurement, as an in-place rank-2 downdate.

With ``H`` non-zero only on the 5 entries ``J`` (robot, landmark), ``H P`` is
``H_J P[J, :]`` (P is symmetric: rows, not columns), ``S = H_J P[J, J] H_J^T + R``,
the state moves by ``(H P)^T S^-1 nu`` and the covariance loses
``(H P)^T S^-1 (H P) = M M^T`` with ``M = (L^-1 H P)^T`` (n, 2), ``S = L L^T``.
:func:`rank2_correction` forms ``L^-1 H_J`` and ``(S^-1 nu)^T H_J`` as floats
(a 3x5 matrix), multiplies it with the 5 gathered rows once (``M^T`` and the
state step in one 3 x n product) and hands ``P -= M M^T`` to
:class:`Rank2Downdate`: one BLAS ``dgemm`` with ``beta = 1`` written straight
into the filter's buffer (through the ``dgemm`` pointer SciPy exports for
Cython, since ``scipy.linalg.blas.dgemm`` silently copies a strided ``c``), so
no n x n temporary and no copy of ``P`` is made. O(n^2), nothing O(n^3); the
per-call Python work is a fixed ~20 numpy calls, which is what dominates below
~200 landmarks (issue 20 item 3). ``P`` stays symmetric to the bit: the dgemm
is run on a size padded to :data:`PAD` (the padding rows and columns are
zero), where OpenBLAS computes entries (i, j) and (j, i) with the same kernel
(measured at every odd n up to 200 and 303-2003; unpadded, n = 1003 and 1503
came out asymmetric in the last bit).

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

import ctypes
import functools
import math
from collections.abc import Callable

import numpy as np

from slamcore.planar import geometry as models

#: The covariance buffer's side and every downdate are padded to a multiple of this
#: (see the module docstring: exact symmetry of OpenBLAS's dgemm).
PAD = 16

#: Rows per block of the numpy fallback downdate (no BLAS pointer): small blocks keep
#: the temporary in cache.
ROW_BLOCK_ELEMENTS = 1 << 17
#: Largest panel of the BLAS downdate, in entries of P (rows x m): OpenBLAS runs a
#: dgemm with m n k below 65536 x 4 on one thread (its SMP threshold), k = 2 here.
PANEL_ELEMENTS = 1 << 17

#: :func:`rank2_correction` outcomes.
APPLIED, GATED, INDEFINITE = "applied", "gated", "indefinite"

#: Gauss-Newton iterations and step halvings of :func:`damped_iterated_step`.
MAX_ITERATIONS = 20
MAX_HALVINGS = 30
#: Relative decrease of the MAP cost below which the iteration has converged.
COST_TOLERANCE = 1e-10


def padded(n: int) -> int:
    """``n`` rounded up to a multiple of :data:`PAD`."""
    return -(-n // PAD) * PAD


@functools.cache
def _blas_dgemm():
    """Fortran ``dgemm`` from SciPy's Cython BLAS table, or None where it is not exported."""
    try:
        from scipy.linalg import cython_blas

        capsule = cython_blas.__pyx_capi__["dgemm"]
        name = ctypes.pythonapi.PyCapsule_GetName
        name.restype, name.argtypes = ctypes.c_char_p, [ctypes.py_object]
        pointer = ctypes.pythonapi.PyCapsule_GetPointer
        pointer.restype, pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
        address = pointer(capsule, name(capsule))
    except (ImportError, AttributeError, KeyError, ValueError):
        return None
    return ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 13)(address)


@functools.cache
def _blas_threads():
    """OpenBLAS's ``get_num_threads`` of the library behind :func:`_blas_dgemm`, or None."""
    try:
        from scipy.linalg import cython_blas

        lib = ctypes.CDLL(cython_blas.__file__)
    except (ImportError, OSError):
        return None
    for name in (
        "scipy_openblas_get_num_threads",
        "scipy_openblas_get_num_threads64_",
        "openblas_get_num_threads",
        "openblas_get_num_threads64_",
    ):
        get = getattr(lib, name, None)
        if get is not None:
            get.restype, get.argtypes = ctypes.c_int, []
            return get
    return None


class Rank2Downdate:
    """``P[:m, :m] -= W[:2, :m]^T W[:2, :m]`` in place on a C-ordered (dim, dim) buffer ``P``.

    ``W`` is a (3, dim) scratch array owned here (row 2 is free for the
    caller). When BLAS may use several threads the downdate runs in panels
    of P's rows, each one dgemm small enough (:data:`PANEL_ELEMENTS`) that
    OpenBLAS keeps it on one thread: a whole-matrix dgemm goes multithreaded
    from about n = 500, and on the loaded 2-core machine that made it 40-100x
    slower (68 ms against 0.7 ms at n = 1003, the same for the plain dgemm
    floor of ``benchmarks/bench_ekf_update.py --threads 0``). Pinned to one
    thread (``threadpoolctl``), it is one dgemm over the whole matrix, as the
    panels' per-call cost showed at n = 500 (1.3x). The calls' arguments are
    built once per ``m`` (the buffer's addresses are fixed). ``use_blas=False``
    (or no BLAS pointer) takes a row-blocked numpy form, for comparison in tests.
    """

    def __init__(self, P: np.ndarray, use_blas: bool = True):
        if P.ndim != 2 or P.shape[0] != P.shape[1] or not P.flags.c_contiguous:
            raise ValueError("Rank2Downdate needs a C-contiguous square buffer")
        dim = P.shape[0]
        self._P = P
        self.W = np.zeros((3, dim))
        self._use_blas = use_blas and _blas_dgemm() is not None  # looked up once, on first use
        self._init_calls()

    def _init_calls(self) -> None:
        """The dgemm constants; plans hold raw addresses of ``P`` and ``W``, so they are
        rebuilt lazily (and never copied: see ``__getstate__``)."""
        self._consts = (
            ctypes.c_char(b"N"),
            ctypes.c_char(b"T"),
            ctypes.c_int(2),
            ctypes.c_double(-1.0),
            ctypes.c_double(1.0),
            ctypes.c_int(self._P.shape[0]),
        )
        self._plans: dict[tuple[int, int], tuple[list[tuple], list[ctypes.c_int]]] = {}

    def __getstate__(self) -> dict:
        # A copied or unpickled downdate must not keep the original buffers' addresses.
        return {k: v for k, v in self.__dict__.items() if k not in ("_consts", "_plans")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._init_calls()

    def _plan(self, m: int, rows: int) -> list[tuple]:
        """The dgemm argument tuples of ``m`` in panels of ``rows`` rows (the last two kept)."""
        plan = self._plans.get((m, rows))
        if plan is not None:
            return plan[0]
        no, tr, two, minus, one, ld = (ctypes.addressof(c) for c in self._consts)
        dim, w, p = self._P.shape[0], self.W.ctypes.data, self._P.ctypes.data
        ints = [ctypes.c_int(m)]
        calls = []
        for r0 in range(0, m, rows):
            ints.append(ctypes.c_int(min(rows, m - r0)))
            # column-major: C = P^T, A = W^T (dim x 3), both leading dimension dim;
            # C[:m, r0:r1] += -1 A[:m, :2] A[r0:r1, :2]^T (P's rows r0:r1)
            calls.append(
                (
                    no,
                    tr,
                    ctypes.addressof(ints[0]),
                    ctypes.addressof(ints[-1]),
                    two,
                    minus,
                    w,
                    ld,
                    w + 8 * r0,
                    ld,
                    one,
                    p + 8 * dim * r0,
                    ld,
                )
            )
        if len(self._plans) >= 2:
            self._plans.clear()
        self._plans[(m, rows)] = (calls, ints)
        return calls

    def __call__(self, m: int) -> None:
        if self._use_blas:
            rows = max(PAD, min(m, PANEL_ELEMENTS // m) // PAD * PAD)
            threads, dgemm = _blas_threads(), _blas_dgemm()
            if rows < m and threads is not None and threads() == 1:
                rows = m
            for args in self._plan(m, rows):
                dgemm(*args)
            return
        Wt = self.W[:2, :m]
        W = Wt.T
        P = self._P
        step = min(64, max(8, ROW_BLOCK_ELEMENTS // m))
        for r0 in range(0, m, step):
            blk = P[r0 : min(r0 + step, m), :m]
            np.subtract(blk, W[r0 : r0 + step] @ Wt, out=blk)


def cholesky_2x2(S) -> tuple[float, float, float] | None:
    """``S = L L^T`` with ``L = [[a, 0], [b, c]]``; None unless S is finite positive definite."""
    return cholesky_2x2_floats(float(S[0, 0]), float(S[1, 0]), float(S[1, 1]))


def cholesky_2x2_floats(s00: float, s10: float, s11: float) -> tuple[float, float, float] | None:
    """:func:`cholesky_2x2` of ``[[s00, s10], [s10, s11]]`` given as floats."""
    if not (s00 > 0.0 and s00 < math.inf):
        return None
    a = math.sqrt(s00)
    b = s10 / a
    c2 = s11 - b * b
    if not (c2 > 0.0 and c2 < math.inf):
        return None
    return a, b, math.sqrt(c2)


def rank2_correction(
    x: np.ndarray,
    n: int,
    rows: np.ndarray,
    H,
    S: tuple[float, float, float],
    nu: tuple[float, float],
    downdate: Rank2Downdate,
    gate: float = math.inf,
    move_state: bool = True,
) -> str:
    """Correct the state buffer ``x`` and the downdate's ``P`` in place (state size ``n``).

    Args:
        x: the state buffer (dim,), zero beyond ``n``.
        rows: P's rows ``J`` (5, dim), zero beyond column ``n``.
        H: the two rows (5 floats each) of the Jacobian over ``J``.
        S: ``(s00, s01, s11)`` of the innovation covariance; nu: the innovation.

    Returns :data:`GATED` when ``nu^T S^-1 nu`` exceeds ``gate`` and
    :data:`INDEFINITE` when ``S`` is not positive definite (both leave ``x``
    and ``P`` untouched), else :data:`APPLIED`. ``move_state=False`` applies
    only the covariance downdate (the caller moved the state). Angles in ``x``
    are not wrapped here.
    """
    chol = cholesky_2x2_floats(S[0], S[1], S[2])
    if chol is None:
        return INDEFINITE
    a, b, c = chol
    w0 = nu[0] / a  # w = L^-1 nu, |w|^2 = nu^T S^-1 nu
    w1 = (nu[1] - b * w0) / c
    if w0 * w0 + w1 * w1 > gate:
        return GATED
    u1 = w1 / c if move_state else 0.0  # u = S^-1 nu = L^-T w
    u0 = (w0 - b * u1) / a if move_state else 0.0
    l10, ia, ic = -b / (a * c), 1.0 / a, 1.0 / c  # L^-1 = [[1/a, 0], [-b/(a c), 1/c]]
    (p0, p1, p2, p3, p4), (q0, q1, q2, q3, q4) = H
    W = downdate.W
    # [M^T; (S^-1 nu)^T H P] = [L^-1 H_J; (S^-1 nu)^T H_J] P[J, :], beyond n zero
    np.dot(
        np.array(
            (
                ia * p0,
                ia * p1,
                ia * p2,
                ia * p3,
                ia * p4,
                l10 * p0 + ic * q0,
                l10 * p1 + ic * q1,
                l10 * p2 + ic * q2,
                l10 * p3 + ic * q3,
                l10 * p4 + ic * q4,
                u0 * p0 + u1 * q0,
                u0 * p1 + u1 * q1,
                u0 * p2 + u1 * q2,
                u0 * p3 + u1 * q3,
                u0 * p4 + u1 * q4,
            )
        ).reshape(3, 5),
        rows,
        out=W,
    )
    if move_state:
        x += W[2]
    downdate(-(-n // PAD) * PAD)
    return APPLIED


def map_cost(
    a: np.ndarray, x0J: np.ndarray, PJ: np.ndarray, z: np.ndarray, Rinv: np.ndarray
) -> tuple[float, np.ndarray]:
    """MAP cost ``V`` at ``x_J = x0_J + P_JJ a`` (robot 3 + landmark 2), and that ``x_J``."""
    dx = PJ @ a
    xJ = x0J + dx
    r = models.innovation(z, models.observe(xJ[:3], xJ[3:5]))
    return 0.5 * float(a @ dx) + 0.5 * float(r @ Rinv @ r), xJ


def damped_iterated_step(
    x0J: np.ndarray,
    PJ: np.ndarray,
    z: np.ndarray,
    R: np.ndarray,
    jacobian: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray | None:
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
