"""The correction step's algebra of the monocular EKF (:class:`filters.mono_ekf.MonoEkf`).

Each measurement's Jacobian is non-zero on the 7 pose columns and on one
landmark's block only, so ``P H^T`` and ``S`` are gathered from those columns
(``idx``: the landmarks' padded state indices (k, 7), padding repeating the
first index with zero Jacobian columns) instead of multiplying a dense ``H``:
O(n k) for ``P H^T`` and one O(n^2 k) downdate ``P -= M M^T``.

Pixels are in pixels, ``var`` the pixel variance (px^2). The state ``x`` (n,)
and covariance ``P`` (n, n) are updated in place.
"""

from __future__ import annotations

import functools

import numpy as np

from filters import landmark_params as lp
from slamcore.errors import GraphSlamError


@functools.cache
def _blas_pools():
    """threadpoolctl's controller of the loaded BLAS pools, found once (a lookup walks
    the process's libraries)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def innovation_blocks(
    P: np.ndarray, idx: np.ndarray, Hp: np.ndarray, Hl: np.ndarray, var: float
) -> np.ndarray:
    """Per-landmark ``S_i = H_i P H_i^T + var I`` (k, 2, 2) from the pose and landmark blocks.

    ``idx`` (k, 7) state indices of the landmarks, ``Hp`` (k, 2, 7) and ``Hl``
    (k, 2, 7) the pixel Jacobians w.r.t. ``[p, q]`` and the landmark.
    """
    P_pl = P[:7][:, idx].transpose(1, 0, 2)  # (k, 7, 7)
    P_ll = P[idx[:, :, None], idx[:, None, :]]  # (k, 7, 7)
    HpT = Hp.transpose(0, 2, 1)
    S = Hp @ P[:7, :7] @ HpT + Hl @ P_ll @ Hl.transpose(0, 2, 1)
    X = Hp @ P_pl @ Hl.transpose(0, 2, 1)
    S += X + X.transpose(0, 2, 1) + var * np.eye(2)
    return S


def gain_blocks(
    P: np.ndarray, idx: np.ndarray, Hp: np.ndarray, Hl: np.ndarray, var: float
) -> tuple[np.ndarray, np.ndarray]:
    """``P H^T`` (n, 2k) from the pose and landmark columns, and the joint ``S`` (2k, 2k).

    Arguments as :func:`innovation_blocks`; measurement ``i`` owns rows and
    columns ``2i, 2i + 1``.
    """
    n, k = len(P), len(idx)
    Hp2 = Hp.reshape(2 * k, 7)
    PHt = P[:, :7] @ Hp2.T + np.einsum("nkj,kaj->nka", P[:, idx], Hl).reshape(n, 2 * k)
    S = Hp2 @ PHt[:7] + np.einsum("kaj,kjm->kam", Hl, PHt[idx]).reshape(2 * k, 2 * k)
    S = 0.5 * (S + S.T) + var * np.eye(2 * k)
    return PHt, S


def apply_correction(x: np.ndarray, P: np.ndarray, PHt: np.ndarray, S: np.ndarray, nu: np.ndarray) -> None:
    """EKF correction in place from ``P H^T`` (n, m), ``S`` (m, m) and the innovation ``nu`` (m,) px.

    ``P -= M M^T`` with ``M = P H^T L^-T`` (``S = L L^T``) keeps ``P``
    symmetric without a separate symmetrisation; the quaternion is then
    renormalised (:func:`normalise_quaternion`).

    BLAS runs on one thread here: the multi-threaded solve differs in the last bits
    from the single-threaded one, so anchored-landmark runs (``landmark_param =
    "ahp"``) on KITTI 07 ended with other bits under OPENBLAS_NUM_THREADS=2 than =1
    (fifteenth hostile pass). Pinned, a seed gives the same bits on any core count, at
    no measured cost (KITTI 07 camera alone: 1.96-1.98 s against 1.90-1.93 s of
    processing).
    """
    with _blas_pools().limit(limits=1, user_api="blas"):
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:  # before x or P changed: the estimate so far stands
            # a pixel noise of 1e-9 px left S at the state's round-off (hostile pass 17)
            raise GraphSlamError(
                "monocular EKF: the measurements' innovation covariance is not positive definite: "
                "the pixel noise is too small for the state's round-off ([tracker] sigma_px?)"
            ) from None
        M = np.linalg.solve(L, PHt.T).T  # (n, m) = P H^T L^-T
        x += M @ np.linalg.solve(L, nu)
        P -= M @ M.T
    normalise_quaternion(x, P)


def gated_correction(
    x: np.ndarray,
    P: np.ndarray,
    idx: np.ndarray,
    Hp: np.ndarray,
    Hl: np.ndarray,
    nu: np.ndarray,
    S: np.ndarray,
    var: float,
    gate: float,
) -> np.ndarray:
    """Gate each measurement alone, correct with the kept ones in one batch; returns the
    kept mask (k,).

    ``nu`` (k, 2) px innovations and ``S`` (k, 2, 2) their covariances at the
    current state, ``idx``, ``Hp``, ``Hl`` as :func:`innovation_blocks`;
    kept: squared Mahalanobis distance below ``gate``. The sequential search's
    step (what the RANSAC rescue does, without re-predicting an unchanged state).
    """
    d2 = np.einsum("ki,ki->k", nu, np.linalg.solve(S, nu[:, :, None])[:, :, 0])
    ok = d2 < gate
    if ok.any():
        PHt, S_ok = gain_blocks(P, idx[ok], Hp[ok], Hl[ok], var)
        apply_correction(x, P, PHt, S_ok, nu[ok].reshape(-1))
    return ok


def normalise_quaternion(x: np.ndarray, P: np.ndarray) -> None:
    """``q <- q / |q|`` (``x[3:7]``) in place, ``P`` through the normalisation's Jacobian."""
    q = x[3:7]
    nq = float(np.linalg.norm(q))
    J = (np.eye(4) - np.outer(q, q) / nq**2) / nq
    x[3:7] = q / nq
    P[3:7, :] = J @ P[3:7, :]
    P[:, 3:7] = P[:, 3:7] @ J.T


def one_point_ransac(
    rng: np.random.Generator,
    K: np.ndarray,
    x: np.ndarray,
    kinds: np.ndarray,
    idx: np.ndarray,
    z: np.ndarray,
    nu: np.ndarray,
    PHt: np.ndarray,
    S: np.ndarray,
    var: float,
    *,
    max_hypotheses: int,
    inlier_sigmas: float,
) -> np.ndarray:
    """Low-innovation inliers (k,) bool of the best single-measurement hypothesis.

    One-point RANSAC (Civera et al., JFR 2010). ``K`` (3, 3) intrinsics,
    ``x`` (n,) the state, ``kinds`` (k,) and ``idx`` (k, 7) the measured
    landmarks' kinds and state indices; ``z``, ``nu`` (k, 2) px: measurements
    and innovations at the current state; ``PHt`` (n, 2k), ``S`` (2k, 2k)
    from :func:`gain_blocks`. All hypotheses (at most ``max_hypotheses``,
    drawn with ``rng`` when there are more measurements) are evaluated in
    one batched projection: cheaper in numpy than stopping early. A
    hypothesis supports the measurements it predicts within
    ``inlier_sigmas`` pixel sigmas.
    """
    k = len(idx)
    m = min(max_hypotheses, k)
    hyp = rng.permutation(k)[:m] if m < k else np.arange(k)
    # x_j = x + P H_j^T S_j^-1 nu_j for every hypothesis j at once
    Sj = np.stack([S[2 * j : 2 * j + 2, 2 * j : 2 * j + 2] for j in hyp])
    g = np.linalg.solve(Sj, nu[hyp][:, :, None])[:, :, 0]  # (m, 2)
    cols = PHt.reshape(len(PHt), k, 2)[:, hyp, :]  # (n, m, 2)
    X = x[:, None] + np.einsum("nmi,mi->nm", cols, g)  # (n, m)
    q = X[3:7].T
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    uv_h, hz_h = lp.project_hypotheses(K, X[0:3].T, q, kinds, X[idx].transpose(2, 0, 1))
    e = z[None] - uv_h
    with np.errstate(invalid="ignore"):
        sup = (hz_h > 0) & (np.einsum("mki,mki->mk", e, e) < (inlier_sigmas**2) * var)
    return sup[int(np.argmax(sup.sum(axis=1)))]  # first of the best: repeatable
