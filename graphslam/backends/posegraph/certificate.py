"""A certificate of global optimality for a pose-graph estimate (SE-Sync's check).

What it certifies is SE-Sync's problem (Rosen et al., "SE-Sync: a certifiably
correct algorithm for synchronization over the special Euclidean group", IJRR
2019): the same edges with isotropic weights (:func:`slamcore.posegraph.
fixed_information` ``isotropic``) and the chordal rotation distance,

    F(t, R) = sum_e  p_R/4 ||R_j - R_i R_ij||_F^2 + p_t/2 ||t_j - t_i - R_i t_ij||^2,

which equals gtsam's cost ``0.5 sum ||whitened residual||^2`` to second order
when an edge's information is isotropic, and is its standard convex-relaxable
stand-in when it is not. The full-information geodesic cost the solver
minimises has no cheap certificate.

How: the estimate is refined on ``F`` by gtsam's LM (``FrobeniusBetweenFactor``,
whose error is ``vec(T_j - T_i T_ij)``), then weak Lagrangian duality gives a
lower bound on every feasible point. With ``X = [t | R]`` (d x (N + dN)), ``F =
tr(X M X^T)`` for a sparse PSD ``M``; for the rotation blocks' multipliers
``Lambda_i = sym((M X^T)_i R_i)`` and ``S = M - blkdiag(0, Lambda)``, if ``S +
eta I_R`` is positive semidefinite on the translation-grounded space then every
feasible ``Y`` has ``F(Y) >= sum_i tr(Lambda_i) - eta d N``. The gap between
that bound and ``F`` at the refined estimate bounds its suboptimality; no
exact stationarity is needed for the bound to hold. Positive definiteness is
read off the pivots of an LU factorisation without pivoting on a symmetric
fill-reducing ordering (Sylvester's law of inertia); SciPy's SuperLU does
that, and no sparse Cholesky ships with the project's dependencies.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import gtsam
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from graphslam.backends import deep_stack
from graphslam.backends.posegraph import factors as fx
from slamcore import posegraph as pg

#: Relative gap at or under which the refined estimate is called the global optimum.
CERTIFIED_REL_GAP = 1e-3
#: Slack ``eta`` tried on the rotation blocks, as fractions of ``F / (d N)``: the
#: smallest that passes is used (the bound loses ``eta d N``, that fraction of F);
#: the largest is a tenth of :data:`CERTIFIED_REL_GAP`, so a pass is not decided
#: by rounding at the threshold.
ETA_LADDER = (1e-8, 1e-6, 1e-4)
#: The refinement's LM: a loose tolerance suffices (the bound holds at any point;
#: tighter only narrows the gap, and the chordal tail converges linearly: on
#: sphere2500 1e-6 takes 12 iterations and leaves a 1e-4 gap, 1e-8 takes 27).
REFINE_RELATIVE_TOL = 1e-6
REFINE_MAX_ITERATIONS = 50

#: What the certificate covers, written beside it in ``metrics.json``.
CERTIFIES = (
    "SE-Sync's problem: the kept edges with isotropic weights (SE-Sync's, from each "
    "information matrix) and the chordal rotation distance; 'certified' means the "
    "estimate refined on that problem is within relative_gap of its global optimum "
    "(weak Lagrangian duality). It does not certify the full-information cost the "
    "solver minimised, whose estimate is max_translation_change_m / "
    "max_rotation_change_deg from the refined one."
)


@dataclass(frozen=True)
class Certificate:
    """The outcome of :func:`certify`.

    Attributes:
        certified: the refined estimate's relative gap is at most
            :data:`CERTIFIED_REL_GAP`.
        chordal_cost: ``F`` at the refined estimate. lower_bound: the dual bound
            on ``F`` over every feasible estimate (None when no ``eta`` passed).
        relative_gap: ``(chordal_cost - lower_bound) / chordal_cost`` (None likewise).
        eta: the slack that passed. negative_pivots: the negative eigenvalue
            count of the grounded ``S + eta I_R`` at the largest slack tried, when
            none passed (else 0).
        max_translation_change_m, max_rotation_change_deg: from the estimate to
            its refinement (the first pose is held).
        iterations: the refinement's LM iterations. refine_stopped: its time budget
            ended it before convergence. wall_s: the whole check's time.
    """

    certified: bool
    relative_gap: float | None
    chordal_cost: float
    lower_bound: float | None
    eta: float | None
    negative_pivots: int
    max_translation_change_m: float
    max_rotation_change_deg: float
    iterations: int
    refine_stopped: bool
    wall_s: float

    def to_dict(self) -> dict:
        """The fields in their order, then what the certificate covers (metrics.json)."""
        return {**asdict(self), "covers": CERTIFIES}


def uncheckable(graph: pg.PoseGraph, keep: np.ndarray) -> str | None:
    """Why ``graph``'s kept edges (``keep`` (M,) bool) admit no certificate, or None."""
    if len(graph.fixed) > 1:
        return "several FIX poses: SE-Sync's problem has no anchors"
    rows = graph.index_of(graph.edges[keep].ravel()).reshape(-1, 2)
    parts = pg.components(graph.n_poses, rows)
    if len(parts) > 1:
        return f"the kept edges leave the graph in {len(parts)} parts"
    return None


class CheckInterrupted(Exception):
    """``should_stop`` ended the check (a signal): there is no certificate to give."""


def certify(
    graph: pg.PoseGraph,
    params: np.ndarray,
    keep: np.ndarray,
    budget_s: float | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> Certificate:
    """Refine ``params`` ((N, P), the graph's parameters) on SE-Sync's problem over the
    edges ``keep`` ((M,) bool; see :func:`uncheckable` first) and certify the result;
    ``budget_s``: seconds the refinement may take (None: no limit); ``should_stop``:
    asked between its iterations, True raises :class:`CheckInterrupted`."""
    t0 = time.perf_counter()
    d, n = graph.dim, graph.n_poses
    rows = graph.index_of(graph.edges[keep].ravel()).reshape(-1, 2)
    weights = pg.fixed_information(graph.information[keep], "isotropic", d)
    p_t, p_R = weights[:, 0, 0], weights[:, d, d]
    Z = np.array([fx.pose(m, graph.rotation).matrix() for m in graph.measurements[keep]])
    T0 = np.array([fx.pose(p, graph.rotation).matrix() for p in params])
    tree = len(rows) == n - 1  # connected (see uncheckable) with no loop
    # a tree's optimum costs 0, a bound every estimate meets (F >= 0: M is PSD), so
    # neither the refinement nor the factorisation is needed (a 100 000-pose chain: 7 s)
    T, iterations, ended = (T0, 0, None) if tree else refine(T0, rows, Z, p_t, p_R, budget_s, should_stop)
    if ended == "signal":
        raise CheckInterrupted("a signal stopped the check")
    M = data_matrix(n, d, rows, Z, p_t, p_R)
    X = stacked(T)
    F = float(np.einsum("ij,ji->", X, M @ X.T))
    bound, eta, negative = (0.0, 0.0, 0) if tree else dual_bound(M, X, n, d, F)
    gap = None if bound is None else max(F - bound, 0.0) / max(F, _floor(M))
    dR = np.einsum("nij,nik->njk", T0[:, :d, :d], T[:, :d, :d])
    cos = np.clip((np.trace(dR, axis1=1, axis2=2) - (d - 2)) / 2.0, -1.0, 1.0)
    return Certificate(
        certified=gap is not None and gap <= CERTIFIED_REL_GAP,
        chordal_cost=F,
        lower_bound=bound,
        relative_gap=gap,
        eta=eta,
        negative_pivots=negative,
        max_translation_change_m=float(np.linalg.norm(T[:, :d, d] - T0[:, :d, d], axis=1).max()),
        max_rotation_change_deg=float(np.degrees(np.arccos(cos)).max()),
        iterations=iterations,
        refine_stopped=ended == "budget",
        wall_s=time.perf_counter() - t0,
    )


def refine(
    T0: np.ndarray,
    rows: np.ndarray,
    Z: np.ndarray,
    p_t: np.ndarray,
    p_R: np.ndarray,
    budget_s: float | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[np.ndarray, int, str | None]:
    """(N, d+1, d+1) poses at a local minimum of ``F`` from ``T0`` (the first pose
    held, which costs nothing: ``F`` is invariant to a global rigid motion), the
    LM's iterations, and what ended it before convergence: ``"budget"`` (``budget_s``
    seconds; the bound still holds there, only the gap widens), ``"signal"``
    (``should_stop()``), else None. ``rows`` (K, 2) pose indices,
    ``Z`` (K, d+1, d+1)."""
    t0 = time.perf_counter()
    d = T0.shape[1] - 1
    # one body for both dimensions: gtsam's 2-D and 3-D classes, typed loosely
    Pose: Any = _pose2 if d == 2 else gtsam.Pose3
    between: Any = gtsam.FrobeniusBetweenFactorPose2 if d == 2 else gtsam.FrobeniusBetweenFactorPose3
    prior: Any = gtsam.PriorFactorPose2 if d == 2 else gtsam.PriorFactorPose3
    values = gtsam.Values()
    for k, T in enumerate(T0):
        values.insert(k, Pose(T))
    graph = gtsam.NonlinearFactorGraph()
    for (i, j), z, wt, wr in zip(rows.tolist(), Z, p_t, p_R, strict=True):
        # gtsam's error is 0.5 e^T W e of e = vec(T_j - T_i Z), column-major; the
        # bottom row is constant (weight 1, no effect)
        w = np.ones((d + 1, d + 1))
        w[:d, :d], w[:d, d] = wr / 2.0, wt
        graph.add(between(i, j, Pose(z), gtsam.noiseModel.Diagonal.Precisions(w.T.ravel())))
    graph.add(prior(0, Pose(T0[0]), gtsam.noiseModel.Isotropic.Sigma(3 * (d - 1), 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(REFINE_RELATIVE_TOL)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    # gtsam eliminates recursively: a long chain needs the deep stack (100 000 poses)
    ended = deep_stack.call(_iterate, optimizer, params, t0, budget_s, should_stop)
    out = optimizer.values()
    at = out.atPose2 if d == 2 else out.atPose3
    return (np.array([at(k).matrix() for k in range(len(T0))]), int(optimizer.iterations()), ended)


def _iterate(
    optimizer: gtsam.LevenbergMarquardtOptimizer,
    params: gtsam.LevenbergMarquardtParams,
    t0: float,
    budget_s: float | None,
    should_stop: Callable[[], bool] | None,
) -> str | None:
    """gtsam's own LM loop, written out so that the time budget or a signal can end
    it; what did (see :func:`refine`)."""
    error = optimizer.error()
    for _ in range(REFINE_MAX_ITERATIONS):
        if should_stop is not None and should_stop():
            return "signal"
        optimizer.iterate()
        previous, error = error, optimizer.error()
        if gtsam.checkConvergence(params, previous, error):
            return None
        if budget_s is not None and time.perf_counter() - t0 > budget_s:
            return "budget"
    return None


def _pose2(T: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(T[0, 2], T[1, 2], np.arctan2(T[1, 0], T[0, 0]))


def stacked(T: np.ndarray) -> np.ndarray:
    """``X = [t_1 .. t_N | R_1 .. R_N]`` (d, N + dN) of poses ``T`` (N, d+1, d+1),
    translations shifted so that ``t_1 = 0`` (the grounded gauge)."""
    n, d = len(T), T.shape[1] - 1
    X = np.empty((d, n + d * n))
    X[:, :n] = (T[:, :d, d] - T[0, :d, d]).T
    X[:, n:] = T[:, :d, :d].transpose(1, 0, 2).reshape(d, d * n)
    return X


def data_matrix(
    n: int, d: int, rows: np.ndarray, Z: np.ndarray, p_t: np.ndarray, p_R: np.ndarray
) -> sp.csc_matrix:
    """The sparse PSD ``M`` ((N + dN) square) with ``F(X) = tr(X M X^T)``.

    Per edge, the rotation term is ``w ||X A||_F^2`` with ``A``'s rows ``I`` at
    ``R_j`` and ``-R_ij`` at ``R_i`` (``w = p_R/4``), the translation term ``u (X
    a)^2`` with ``a = +1`` at ``t_j``, ``-1`` at ``t_i``, ``-t_ij`` at ``R_i`` (``u =
    p_t/2``); ``M`` sums ``w A A^T + u a a^T``, written out block by block.
    """
    i, j = rows[:, 0], rows[:, 1]
    R, t = Z[:, :d, :d], Z[:, :d, d]
    w, u = p_R / 4.0, p_t / 2.0
    r_i = n + d * i[:, None] + np.arange(d)  # (K, d) columns of R_i
    r_j = n + d * j[:, None] + np.arange(d)
    ri_a, ri_b = np.broadcast_arrays(r_i[:, :, None], r_i[:, None, :])  # (K, d, d)
    rj_a, ri_c = np.broadcast_arrays(r_j[:, :, None], r_i[:, None, :])
    eye = np.eye(d)
    blocks = [
        # w (I on R_j, R_j) + w (R R^T = I on R_i, R_i) + u t t^T on (R_i, R_i)
        (ri_a, ri_b, w[:, None, None] * eye + u[:, None, None] * t[:, :, None] * t[:, None, :]),
        (rj_a, rj_a.transpose(0, 2, 1), w[:, None, None] * np.broadcast_to(eye, R.shape)),
        (rj_a, ri_c, -w[:, None, None] * R.transpose(0, 2, 1)),  # (R_j, R_i) = -w R^T
        (ri_c.transpose(0, 2, 1), rj_a.transpose(0, 2, 1), -w[:, None, None] * R),
        # translations: u on (t_j, t_j), (t_i, t_i); -u on (t_i, t_j) both ways
        (np.stack([j, i, i, j], 1), np.stack([j, i, j, i], 1), u[:, None] * [1, 1, -1, -1]),
        # cross terms t with R_i: -u t on (t_j, R_i), +u t on (t_i, R_i), and transposed
        (np.repeat(j[:, None], d, 1), r_i, -u[:, None] * t),
        (r_i, np.repeat(j[:, None], d, 1), -u[:, None] * t),
        (np.repeat(i[:, None], d, 1), r_i, u[:, None] * t),
        (r_i, np.repeat(i[:, None], d, 1), u[:, None] * t),
    ]
    r = np.concatenate([np.ravel(b[0]) for b in blocks])
    c = np.concatenate([np.ravel(b[1]) for b in blocks])
    v = np.concatenate([np.ravel(b[2]) for b in blocks])
    size = n + d * n
    return sp.csc_matrix((v, (r, c)), shape=(size, size))


def multipliers(M: sp.csc_matrix, X: np.ndarray, n: int, d: int) -> np.ndarray:
    """(N, d, d) ``Lambda_i = sym((M X^T)_i R_i)``: the rotation constraints'
    multipliers that make ``(M - blkdiag(0, Lambda)) X^T`` vanish at a critical point."""
    G = (M @ X.T)[n:].reshape(n, d, d)  # (M X^T)_i, the rows of R_i
    R = X[:, n:].reshape(d, n, d).transpose(1, 0, 2)
    B = G @ R
    return 0.5 * (B + B.transpose(0, 2, 1))


def dual_bound(
    M: sp.csc_matrix, X: np.ndarray, n: int, d: int, F: float
) -> tuple[float | None, float | None, int]:
    """``(lower bound, eta, negative pivots)``: the smallest slack of
    :data:`ETA_LADDER` for which the grounded ``S + eta I_R`` is positive definite,
    and the bound ``sum tr(Lambda_i) - eta d N`` it gives; ``(None, None, k)`` when
    none is (``k`` negative pivots at the largest)."""
    lam = multipliers(M, X, n, d)
    S = (M - sp.block_diag([sp.csc_matrix((n, n)), *lam], format="csc"))[1:, 1:]
    scale = max(F, _floor(M)) / (d * n)
    negative = 0
    for fraction in ETA_LADDER:
        eta = fraction * scale
        shift = sp.diags(np.concatenate([np.zeros(n - 1), np.full(d * n, eta)]))
        negative = negative_pivots((S + shift).tocsc())
        if negative == 0:
            return float(np.trace(lam, axis1=1, axis2=2).sum() - eta * d * n), eta, 0
    return None, None, negative


def negative_pivots(A: sp.csc_matrix) -> int:
    """How many pivots of a symmetric ``A``'s LU factorisation without pivoting (on a
    symmetric ordering) are not positive: 0 iff ``A`` is positive definite. A zero
    pivot (SuperLU: singular) counts as one; an ordering that pivoted rows after all
    (no inertia then) counts as not positive definite."""
    try:
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError:
        return 1
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return 1
    return int(np.count_nonzero(lu.U.diagonal() <= 0.0))


def _floor(M: sp.csc_matrix) -> float:
    """A cost below which ``F`` counts as zero, so that the bound's slack stays above
    rounding when every edge agrees (``F = 0``): ``1e-8`` of ``tr M`` (which is about
    the cost of a 1 m / 1 rad residual on every edge), i.e. residuals of 1e-4."""
    return 1e-8 * float(M.diagonal().sum())
