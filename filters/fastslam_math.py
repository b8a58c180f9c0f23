"""Batched small-matrix helpers of FastSLAM (:mod:`filters.fastslam`), numpy only.

Every function works on stacks over particles: (n, 2, 2) or (n, 3, 3)
covariances, (n, 2) innovations. Resampling and Gaussian draws take the
filter's one random generator, so runs repeat to the bit.
"""

from __future__ import annotations

import math

import numpy as np

from filters.numerics import Recoveries
from filters.numerics import symmetrise as sym
from slamcore.planar.geometry import wrap_angle


def inv2(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and log-determinant of (..., 2, 2) SPD matrices."""
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    inv = np.empty_like(S)
    inv[..., 0, 0] = d / det
    inv[..., 0, 1] = -b / det
    inv[..., 1, 0] = -c / det
    inv[..., 1, 1] = a / det
    return inv, np.log(det)


def quad(nu: np.ndarray, Sinv: np.ndarray) -> np.ndarray:
    """``nu^T Sinv nu`` for (..., 2) and (..., 2, 2)."""
    return np.einsum("...i,...ij,...j->...", nu, Sinv, nu)


def max_var(P: np.ndarray) -> np.ndarray:
    """(n,) largest diagonal entry of each (n, k, k) covariance."""
    return np.max(np.diagonal(P, axis1=-2, axis2=-1), axis=-1)


def positive_definite(P: np.ndarray) -> np.ndarray:
    """(n,) whether each (n, k, k) symmetric matrix (k = 2 or 3) is finite positive
    definite, by its leading principal minors (Sylvester)."""
    a, b, d = P[:, 0, 0], P[:, 0, 1], P[:, 1, 1]
    ok = (a > 0) & (a * d - b * b > 0)
    if P.shape[-1] == 3:
        c, e, f = P[:, 0, 2], P[:, 1, 2], P[:, 2, 2]
        ok &= a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c) > 0
    return ok & np.all(np.isfinite(P), axis=(-2, -1))


def tr(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)




def low_variance_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: (N,) parent indices for normalised ``weights`` (N,).

    One uniform draw; particle ``i`` is copied ``floor(N w_i)`` or
    ``ceil(N w_i)`` times (expected count ``N w_i``), in index order.
    """
    n = weights.shape[0]
    positions = (rng.random() + np.arange(n)) / n
    cdf = np.cumsum(weights)
    cdf[-1] = 1.0  # guard against round-off
    return np.minimum(np.searchsorted(cdf, positions, side="right"), n - 1)


def sample_gaussian(mean: np.ndarray, cov: np.ndarray, rng: np.random.Generator,
                     recoveries: Recoveries | None = None) -> np.ndarray:
    """One draw per row from N(mean (n, 3), cov (n, 3, 3)); a covariance that is
    not positive definite is drawn through its eigen decomposition (negative
    eigenvalues clipped to 0; counted in ``recoveries``)."""
    cov = sym(cov)
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        if recoveries is not None:
            recoveries.add("eig_fallback")
        w, V = np.linalg.eigh(cov)
        chol = V * np.sqrt(np.clip(w, 0.0, None))[..., None, :]
    eps = rng.standard_normal(mean.shape)
    out = mean + np.einsum("nij,nj->ni", chol, eps)
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def logsumexp(a: np.ndarray) -> float:
    m = float(np.max(a))
    return m + math.log(float(np.sum(np.exp(a - m))))
