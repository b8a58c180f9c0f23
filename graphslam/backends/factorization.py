"""Choosing iSAM2's factorisation, and recovering when Cholesky breaks down.

Why a fallback and not QR always: Cholesky factors the normal equations, whose
condition number is the square of the Jacobian's. Graphs with very anisotropic
information (the synthetic world's odometry covariance, rank 2 plus a 1e-7
floor, next to 1e-3 m range noise; community pose graphs whose information
spans 1e7) reach condition numbers near 1e10-1e12. iSAM2 eliminates in its own
incremental order (new variables last) and factors each clique's frontal block
with Eigen's LLT; there a pivot comes out non-positive and gtsam throws
``IndeterminateSystemException``, although the same graph at the same
linearisation point is positive definite (smallest Hessian eigenvalue 1.4e-3
on the synthetic world with sigma_r = 1e-3 m) and a batch Cholesky solve of it
succeeds. Relinearising every variable at every update (threshold 0.01, skip 1)
fails at the same pose, so the linearisation point is not the cause; the
elimination's arithmetic is. QR works on the whitened Jacobian and does not
square the condition number, at 1.22x the time (default synthetic world, iSAM2
without polish, best of two), so ``auto`` keeps
Cholesky (bit-identical results where it works) and switches to QR only when
it fails, by handing every factor to a fresh QR iSAM2 at the current values.
"""

from __future__ import annotations

import typing
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Literal, TypeVar

import gtsam

from slamcore.errors import GraphSlamError

T = TypeVar("T")

#: The type of the config fields that choose a factorisation, and its values.
Factorization = Literal["auto", "cholesky", "qr"]
FACTORIZATIONS: tuple[str, ...] = typing.get_args(Factorization)


def isam2_factorization(params: gtsam.ISAM2Params, name: str) -> gtsam.ISAM2Params:
    """Set ``params``' factorisation: ``qr`` -> QR, ``auto``/``cholesky`` -> Cholesky."""
    if name not in FACTORIZATIONS:
        raise ValueError(f"factorization must be one of {FACTORIZATIONS}, got {name!r}")
    params.setFactorization("QR" if name == "qr" else "CHOLESKY")
    return params


def is_indeterminate(exc: BaseException) -> bool:
    """Whether a gtsam RuntimeError is an indeterminate (not positive definite) system."""
    return isinstance(exc, RuntimeError) and "Indeterminate" in str(exc)


def failed_variable(exc: BaseException) -> str:
    """The ``Symbol: x12`` gtsam names in an indeterminate-system message, else ''."""
    text = str(exc)
    start = text.find("Symbol: ")
    if start < 0:
        return ""
    return text[start + len("Symbol: ") :].split(")")[0]


@contextmanager
def indeterminate_as_error(who: str) -> Iterator[None]:
    """gtsam's indeterminate-system exception met outside an update (iSAM2 reading its
    estimate) as one :class:`GraphSlamError` line naming the variable; any other
    RuntimeError passes unchanged (a bug: the traceback is wanted)."""
    try:
        yield
    except RuntimeError as exc:
        if not is_indeterminate(exc):
            raise
        raise GraphSlamError(
            f"{who}: indeterminate linear system near {failed_variable(exc) or '?'}: a variable "
            "no measurement pins, or information too large beside the rest for float64 "
            "(check the noise settings)"
        ) from None


def rebuild_with_qr(isam: gtsam.ISAM2, params: gtsam.ISAM2Params) -> gtsam.ISAM2:
    """A fresh QR iSAM2 holding every factor of ``isam`` (same order, so factor
    indices keep their meaning) at ``isam``'s values.

    Called after an ``update`` threw: gtsam has by then stored the new factors
    and values but not their elimination, so its factor list and linearisation
    point are complete while its Bayes tree is not.
    """
    return _rebuilt(isam, isam2_factorization(params, "qr"), set())


def rebuild_without(isam: gtsam.ISAM2, params: gtsam.ISAM2Params, keys) -> gtsam.ISAM2:
    """A fresh iSAM2 (``params``' factorisation) holding every factor of ``isam`` that
    involves none of ``keys``, at ``isam``'s values without ``keys``: the variables and
    their measurements are gone. Called after an ``update`` threw, as
    :func:`rebuild_with_qr` is."""
    return _rebuilt(isam, params, set(keys))


def _rebuilt(isam: gtsam.ISAM2, params: gtsam.ISAM2Params, drop: set[int]) -> gtsam.ISAM2:
    """A fresh iSAM2 with ``params`` on ``isam``'s factors and values, less those of ``drop``."""
    factors = gtsam.NonlinearFactorGraph()
    old = isam.getFactorsUnsafe()
    for i in range(old.size()):
        factor = old.at(i)
        if not drop or (factor is not None and drop.isdisjoint(factor.keys())):
            factors.add(factor)
    values = gtsam.Values(isam.getLinearizationPoint())
    for key in drop:
        if values.exists(key):
            values.erase(key)
    fresh = gtsam.ISAM2(params)
    fresh.update(factors, values)
    return fresh


def marginals_or_none(compute: Callable[[], T], notes: list[str]) -> T | None:
    """``compute()`` of marginal covariances, or None, said once in ``notes``, when the
    system is indeterminate: gtsam's ``Marginals`` take Cholesky only, and an estimate
    whose noise spans a million (1e-6 m sightings beside 0.1 m odometry) ended in gtsam's
    bare RuntimeError, with --save-map and a recording a traceback (twentieth hostile
    pass). Any other RuntimeError passes unchanged."""
    try:
        return compute()
    except RuntimeError as exc:
        if not is_indeterminate(exc):
            raise
        note = (
            f"no covariances: the system at the estimate is indeterminate near "
            f"{failed_variable(exc) or '?'} (gtsam's marginals take Cholesky only)"
        )
        if note not in notes:
            notes.append(note)
        return None
