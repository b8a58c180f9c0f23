"""Float64 limits of the filters' covariance algebra, and the recovery counters.

A Kalman downdate ``P - (H P)^T S^-1 (H P)`` leaves, along the measured
direction, a variance close to the measurement's ``R``; its round-off is of
the order of ``eps`` times the largest variance it was subtracted from. When
``R`` is below that, the result is noise: the next ``S`` can come out
indefinite (a square root of a negative number, a singular solve) or the
covariance silently loses definiteness. :func:`floored_noise` raises each
measurement variance to at least :data:`REL_VARIANCE_FLOOR` times the largest
prior variance it is compared with (in measurement units), i.e. one update may
shrink a variance by at most ~7e7 and half the float64 digits stay
significant. Course noise values are orders of magnitude above the floor, so
it only acts on pathological settings (``sigma_r_m = 1e-9``), and each time it
does, it is counted.

:class:`Recoveries` counts what the filters did to survive (floors applied,
damped updates, factorisation fallbacks, skipped updates); runs report it as
``recoveries`` so that a rescued run never looks like a clean one.
"""

from __future__ import annotations

import math

import numpy as np

#: Machine epsilon of float64.
EPS = float(np.finfo(np.float64).eps)
#: Smallest measurement variance relative to the prior variance it updates:
#: sqrt(eps) keeps half of float64's digits in the downdate.
REL_VARIANCE_FLOOR = math.sqrt(EPS)
#: Largest ``odometry_covariance_scale`` of the filters. It multiplies
#: variances, so 1e6 already widens every odometry standard deviation 1000-fold
#: (a 5 cm step noise becomes 50 m per step: the motion model says nothing);
#: beyond it a setting is a typo, and near 1e300 the covariances overflow to
#: inf and their factorisations fail.
MAX_ODOMETRY_COVARIANCE_SCALE = 1e6


def floored_noise(R: np.ndarray, prior_var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R`` (..., 2, 2) with each variance raised to ``REL_VARIANCE_FLOOR * prior_var``.

    Args:
        R: measurement covariances (..., 2, 2).
        prior_var: (..., 2) the largest prior variance each measured component
            is computed from, in its units (e.g. the diagonal of ``H P H^T``
            with P's largest variance).

    Returns:
        ``(R_floored, hit)``, ``hit`` (...,) True where a variance was raised.
        Off-diagonal terms are kept (the raised matrix stays positive definite).
    """
    floor = REL_VARIANCE_FLOOR * np.asarray(prior_var, dtype=float)
    d = np.stack([R[..., 0, 0], R[..., 1, 1]], axis=-1)
    raise_by = np.where(d < floor, floor - d, 0.0)  # NaN floors raise nothing
    hit = np.any(raise_by > 0.0, axis=-1)
    if not np.any(hit):
        return R, hit
    shape = np.broadcast_shapes(np.shape(R), raise_by.shape[:-1] + (2, 2))
    out = np.array(np.broadcast_to(R, shape), dtype=float)
    out[..., 0, 0] += raise_by[..., 0]
    out[..., 1, 1] += raise_by[..., 1]
    return out, hit


#: The chi-square 0.999 quantile with 2 degrees of freedom, ``-2 ln(1 - 0.999)``
#: (closed form for 2 dof; rounded as the association gates write it).
CHI2_2DOF_999 = 13.8155


def symmetrise(P: np.ndarray) -> np.ndarray:
    """``(P + P^T) / 2`` over the last two axes."""
    return 0.5 * (P + np.swapaxes(P, -1, -2))


class Recoveries(dict):
    """Counts of numerical recoveries by kind (a dict of int; JSON-ready).

    Kinds used by the filters: ``noise_floor`` (a measurement variance raised
    by :func:`floored_noise`), ``damped_update`` (an EKF update that took the
    damped iterated step), ``oc_fallback`` (an EKF update that took the
    standard Jacobian because the observability-constrained one was off by
    more than the measurement noise), ``skipped_update`` (an observation dropped because
    its innovation covariance was not positive definite),
    ``joseph_fallback`` (FastSLAM 2.0's proposal covariance recomputed in
    Joseph form), ``eig_fallback`` (a sample drawn through an eigen
    decomposition).
    """

    KINDS = (
        "noise_floor",
        "damped_update",
        "oc_fallback",
        "skipped_update",
        "joseph_fallback",
        "eig_fallback",
    )

    def __init__(self):
        super().__init__({k: 0 for k in self.KINDS})

    def add(self, kind: str, count: int = 1) -> None:
        if kind not in self:
            raise KeyError(f"unknown recovery kind {kind!r}")
        self[kind] += int(count)

    def total(self) -> int:
        return int(sum(self.values()))
