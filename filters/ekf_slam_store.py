"""The state of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`) and its landmark slots.

:class:`SlotStore` owns the numbers that the filter's steps share: the state
``x = [x, y, theta, m1x, m1y, ...]`` and its covariance ``P`` in preallocated
buffers, the landmark slots (id of each slot, slot of each id), the
linearisation points of the observability-constrained Jacobian (the robot pose
predicted for this step and each landmark's first estimate), the BLAS downdate
bound to ``P``'s buffer and an upper bound on ``P``'s largest variance. It is a
part of its own because the filter (prediction, new landmarks, association)
and the correction of :mod:`filters.ekf_slam_correction` both read and write
it: each takes the store as an explicit argument instead of reaching into the
other's attributes, and the buffers, the slots and what is bound to the
buffers change together, only here.

Buffers: sized for ``cap`` landmarks and padded to
:func:`filters.ekf_slam_update.padded` (the downdate's padding); when a
landmark does not fit, :meth:`SlotStore.open_slot` doubles the capacity and
copies the used ``n x n`` block once (amortised O(1) copies per landmark). The
working ``x`` and ``P`` are the views ``xbuf[:n]`` and ``Pbuf[:n, :n]``;
entries beyond ``n`` are zero.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from filters.ekf_slam_update import Rank2Downdate, padded
from slamcore.planar.geometry import wrap_angle


class SlotStore:
    """State vector, covariance and landmark slots of the EKF-SLAM (see the module docstring).

    Attributes:
        cap: landmarks the buffers hold before the next doubling.
        xbuf: (dim,) state buffer; ``xbuf[:n]`` is the state.
        Pbuf: (dim, dim) C-ordered covariance buffer; ``Pbuf[:n, :n]`` is ``P``.
        downdate: the in-place rank-2 downdate bound to ``Pbuf``
            (:class:`filters.ekf_slam_update.Rank2Downdate`).
        diag: view of ``Pbuf``'s diagonal (zero beyond ``n``).
        pmax_ub: upper bound of ``P``'s largest variance; whoever raises a
            variance raises it (:meth:`note_variances`), a downdate only lowers
            variances (the correction's noise floor relies on it).
        n: used state size, 3 + 2 M; 0 before the first pose.
        ids: landmark id of each slot; slot: slot of each landmark id.
        m_first: first estimate (2,) of each slot's landmark (OC).
        x_pred: robot pose predicted for this step (OC).
    """

    def __init__(self, capacity: int):
        self.cap = int(capacity)
        dim = padded(3 + 2 * self.cap)  # the downdate's padding fits (filters.ekf_slam_update)
        self.xbuf = np.zeros(dim)
        self.Pbuf = np.zeros((dim, dim))
        self._bind()
        self.pmax_ub = math.inf
        self.n = 0
        self.ids: list[int] = []
        self.slot: dict[int, int] = {}
        self.m_first: list[np.ndarray] = []
        self.x_pred = np.zeros(3)

    def _bind(self) -> None:
        """The BLAS downdate and the diagonal view bound to the current ``Pbuf``."""
        self.downdate = Rank2Downdate(self.Pbuf)
        self.diag = self.Pbuf.reshape(-1)[:: self.Pbuf.shape[0] + 1]

    @property
    def x(self) -> np.ndarray:
        """The state, a view (n,)."""
        return self.xbuf[: self.n]

    @property
    def P(self) -> np.ndarray:
        """The covariance, a view (n, n)."""
        return self.Pbuf[: self.n, : self.n]

    def start(self, wTb: np.ndarray, cov: np.ndarray) -> None:
        """Hold only the robot pose ``wTb`` (3,) with covariance ``cov`` (empty store)."""
        self.n = 3
        self.xbuf[:3] = wTb
        self.xbuf[2] = wrap_angle(wTb[2])
        self.Pbuf[:3, :3] = cov
        self.x_pred = self.xbuf[:3].copy()

    def load(self, x: np.ndarray, P: np.ndarray, ids: Sequence[int]) -> None:
        """Hold the state ``x`` (3 + 2M,), ``P`` and landmark ids ``ids`` (empty store,
        capacity at least M); the loaded state is taken as both predicted pose and
        first estimates (OC)."""
        M = len(ids)
        self.n = x.size
        self.xbuf[: self.n] = x
        self.xbuf[2] = wrap_angle(x[2])
        self.Pbuf[: self.n, : self.n] = P
        self.x_pred = self.xbuf[:3].copy()
        self.m_first = [self.xbuf[3 + 2 * k : 5 + 2 * k].copy() for k in range(M)]
        self.ids = list(ids)
        self.slot = {lid: k for k, lid in enumerate(self.ids)}

    def open_slot(self, lid: int, m: np.ndarray) -> int:
        """Append landmark ``lid`` at position ``m`` (2,) as its first estimate; its slot.

        Doubles the capacity first when the buffers are full. The caller
        fills the new rows and columns of ``P`` (zero until then) and raises
        :attr:`pmax_ub` with their variances.
        """
        if len(self.ids) >= self.cap:
            self._grow()
        n = self.n
        self.xbuf[n : n + 2] = m
        self.m_first.append(self.xbuf[n : n + 2].copy())
        slot = len(self.ids)
        self.ids.append(lid)
        self.slot[lid] = slot
        self.n = n + 2
        return slot

    def remove_slots(self, slots: Sequence[int]) -> None:
        """Drop the landmarks of ``slots`` from the state: marginalise them out of the
        Gaussian, which is deleting their rows and columns of ``x`` and ``P``. The
        remaining landmarks keep their order and move down to fill the gaps; the
        freed entries of the buffers are zeroed. O(n^2)."""
        drop = set(slots)
        if not drop:
            return
        keep = [k for k in range(len(self.ids)) if k not in drop]
        idx = np.array([0, 1, 2] + [3 + 2 * k + j for k in keep for j in (0, 1)])
        x = self.xbuf[idx]
        P = self.Pbuf[np.ix_(idx, idx)]
        n_old, self.n = self.n, idx.size
        self.xbuf[:n_old] = 0.0
        self.Pbuf[:n_old, :n_old] = 0.0
        self.xbuf[: self.n] = x
        self.Pbuf[: self.n, : self.n] = P
        self.ids = [self.ids[k] for k in keep]
        self.m_first = [self.m_first[k] for k in keep]
        self.slot = {lid: k for k, lid in enumerate(self.ids)}

    def _grow(self) -> None:
        new_cap = 2 * self.cap
        dim = padded(3 + 2 * new_cap)
        n = self.n
        xbuf = np.zeros(dim)
        xbuf[:n] = self.xbuf[:n]
        Pbuf = np.zeros((dim, dim))
        Pbuf[:n, :n] = self.Pbuf[:n, :n]
        self.xbuf, self.Pbuf, self.cap = xbuf, Pbuf, new_cap
        self._bind()

    def note_variances(self, *variances: float) -> None:
        """Raise :attr:`pmax_ub` to cover ``variances`` (variances just raised in ``P``)."""
        self.pmax_ub = max(self.pmax_ub, *variances)

    def landmark_marginals(self) -> np.ndarray:
        """(M, 2, 2) marginal covariance of each slot's landmark."""
        M = len(self.ids)
        i = 3 + 2 * np.arange(M)
        P = self.Pbuf
        out = np.empty((M, 2, 2))
        out[:, 0, 0] = P[i, i]
        out[:, 0, 1] = P[i, i + 1]
        out[:, 1, 0] = P[i + 1, i]
        out[:, 1, 1] = P[i + 1, i + 1]
        return out
